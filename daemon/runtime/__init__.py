"""The runtime: roles, control loop, safety, the Zenoh network, supervisor, plugin loading.
It finds drivers and plugins only through entry points."""
