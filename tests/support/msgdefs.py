"""A rosbag2 message definition held to ROS 2 Jazzy's types, by an independent reader:
``rosbags`` parses the text (each ``MSG:`` section) and its Jazzy type store says what
each type is."""

from __future__ import annotations

from rosbags.typesys import Stores, get_types_from_msg, get_typestore

__all__ = ["JAZZY", "jazzy_differences"]

JAZZY = get_typestore(Stores.ROS2_JAZZY)


def jazzy_differences(text: str, name: str) -> list[str]:
    """How the types the definition ``text`` of ``name`` declares (``name`` and every
    type after a ``MSG:`` line) differ from Jazzy's: fields, their types, array sizes,
    constants (rosbags' generated text of each), and ``name``'s REP 2011 hash. Empty:
    none."""
    parsed = get_types_from_msg(text, name)
    store = get_typestore(Stores.EMPTY)
    store.register(parsed)
    problems = []
    for each in parsed:
        ours = store.generate_msgdef(each, ros_version=2)[0]
        jazzy = JAZZY.generate_msgdef(each, ros_version=2)[0]
        if ours != jazzy:
            problems.append(f"{each}: {ours!r} is not Jazzy's {jazzy!r}")
    if store.hash_rihs01(name) != JAZZY.hash_rihs01(name):
        problems.append(f"{name}: its hash is not Jazzy's")
    return problems
