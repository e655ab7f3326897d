"""The simulated two-tank rig: physics, excitation, tank models, faults."""
