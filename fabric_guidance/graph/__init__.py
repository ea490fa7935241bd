"""Starting the package's nodes as a graph: as processes without `launch` (process_graph: the
demo, the tests, the bench, the simulated study) and the helpers of launch/*.launch.py
(launch_support, which needs the launch packages)."""
