"""Simulation: simulated wearers, the effects a scene can switch on, and the paper's protocols.
Below it only core/ and paths.py; nothing here imports ROS or experiments/.

wearer              SimulatedWearer (the node's simple wearer) and SceneWearer (the engine's)
effects/            the effect library, one module per stage of the loop, and its registry (only
                    what a scene lists is simulated)
scene               scene files (config/scenes/*.yaml), validated
population          wearers sampled from a scene, calibrated by Algorithm 1 in simulation
engine              the headless closed loop, on the same core code as the nodes
protocols           the paper's accuracy and speed experiments
worked_example      the worked example of `fabric-guidance example`
scene_wearer        a scene's wearer side as the ROS graph's wearer_sim runs it (SceneSide)
scene_plan          what a scene changes in the simulated graph (`fabric-guidance demo --scene`)
node_loop           the closed loop built as the pressure_controller node builds it (NodeLoop)

The Discussion studies built on NodeLoop are in experiments/discussion/.
"""
