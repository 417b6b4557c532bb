"""The closed-loop camera simulator: the rig loop, the perturbation protocol, data collection, previews, the exposure
sweep and the oracle (which renders the scene, so it lives with the simulator)."""
