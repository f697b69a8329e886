"""What the tests share: independent stand-ins of the devices (``standin``), stalled-port
scenarios (``stalls``), a real mosquitto (``mqtt_broker``) and a raw MQTT flooder
(``mqtt_flood``), an independent Foxglove WebSocket client (``foxglove_client``), the toy
third device of the docs (``toy_device``), and small helpers (``helpers``). Fixtures are
in ``tests/conftest.py``."""
