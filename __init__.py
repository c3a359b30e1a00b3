"""climbd: control software for legged climbing robots (profiles, drivers, perception and gait
plugins over Zenoh). The layers are ``climbd.daemon`` (contract, algorithms, runtime, cli),
``climbd.drivers`` and ``climbd.plugins``; docs/architecture.md is their map."""
