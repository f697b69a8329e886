"""Surfaces that put a device on other systems, one package each, each a thin adapter
onto the device's motion core (every command they take passes it, through a source of
their own) and its public API (streams, requests, commands, the observation API), each
behind an extra:

* `.mqtt`: the fleet bridge (``pip install -e ".[mqtt]"``);
* `.foxglove`: the live Foxglove server (``pip install -e ".[foxglove]"``);
* `.ros2`: the ROS 2 bridge on Cyclone DDS (``pip install -e ".[ros2]"``);
* `.web`: the web dashboard (``pip install -e ".[web]"``);
* `.inbound`: what every surface that takes commands from outside shares: strict
  command JSON, timestamps and freshness (its refusal reports are the core's
  ``chassis_sdk.core.refusals``);
* `.access`: loopback, Origin and token checks for the WebSocket surfaces.

Every one keeps the contract of the safety model (docs/safety.md), held for all of them
by ``tests/test_surface_contract.py``: a bad message is refused and reported, never
acted on, and never ends the process.
"""
