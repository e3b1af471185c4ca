"""The master side: the host manager (discovery, set-up, liveness, SYNC), its config, the
data plane that turns patch PDOs into forces, and the force nodes that publish them."""
