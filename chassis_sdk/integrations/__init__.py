"""Adapters that put a device on other systems, each behind an extra, each over the
device's public API only (streams, requests, commands, and the observation API):

* `.mqtt`: the fleet bridge (``pip install 'chassis-sdk[mqtt]'``);
* `.foxglove`: the live Foxglove server (``pip install 'chassis-sdk[foxglove]'``);
* `.inbound`: what every surface that can move the robot shares: strict command
  JSON, timestamps and freshness, and rate-limited refusal reports.

Every one keeps the contract of the safety model (docs/safety.md): a bad message is
refused and reported, never acted on, and never ends the process.
"""
