"""What the tests share: independent stand-ins of the devices (``standin``), stalled-port
scenarios (``stalls``), a real mosquitto (``mqtt_broker``), the MQTT bridge's dashboard
and clients (``mqtt``) and a raw MQTT flooder (``mqtt_flood``), the real ``chassis-sdk``
in a subprocess (``cli``), an independent Foxglove WebSocket client (``foxglove_client``),
the toy third device of the docs (``toy_device``), the fuzz harness (``fuzz``), and small
helpers (``helpers``). Fixtures are in ``tests/conftest.py``."""
