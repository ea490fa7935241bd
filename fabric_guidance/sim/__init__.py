"""Simulation: simulated wearers and the effects a scene can switch on."""
