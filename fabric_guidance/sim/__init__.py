"""Simulation: simulated wearers, the effects a scene can switch on, and the paper's protocols.

wearer      SimulatedWearer (the node's simple wearer) and SceneWearer (the engine's)
effects     the effect library and its registry (only what a scene lists is simulated)
scene       scene files (config/scenes/*.yaml), validated
population  wearers sampled from a scene, calibrated by Algorithm 1 in simulation
engine      the headless closed loop, on the same core code as the nodes
protocols   the paper's accuracy and speed experiments
headless    the worked example of `fabric-guidance example`
"""
