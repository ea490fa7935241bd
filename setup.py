"""ament_python package setup: colcon in a ROS 2 workspace, pip in the stand-alone .venv.

Runtime dependencies are declared in package.xml (rosdep) and, for the stand-alone path,
pinned in requirements/standalone.txt; install_requires stays empty of them on purpose so
that colcon never pulls the ROS wheels into a workspace.
"""
from glob import glob
import os

from setuptools import find_packages, setup

package_name = 'fabric_guidance'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        (os.path.join('share', package_name, 'launch'), glob('launch/*.launch.py')),
        (os.path.join('share', package_name, 'config'), glob('config/*.xml')),
        (os.path.join('share', package_name, 'config', 'params'), glob('config/params/*.yaml')),
        (os.path.join('share', package_name, 'config', 'hardware'), glob('config/hardware/*.yaml')),
        (os.path.join('share', package_name, 'config', 'calibrations'), glob('config/calibrations/*.yaml')),
        (os.path.join('share', package_name, 'config', 'scenes'), glob('config/scenes/*.yaml')),
        (os.path.join('share', package_name, 'config', 'scenes', 'fit'), glob('config/scenes/fit/*')),
        (os.path.join('share', package_name, 'config', 'rviz'), glob('config/rviz/*.rviz')),
        (os.path.join('share', package_name, 'config', 'foxglove'), glob('config/foxglove/*.json')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='fabric_guidance developers',
    maintainer_email='fabric-guidance@example.org',
    description='Directional guidance through a pneumatic fabric suit (Yokoe et al. 2025).',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'fabric-guidance = fabric_guidance.commands.cli:main',
            'gaze_bridge = fabric_guidance.nodes.gaze_bridge:main',
            'target_selector = fabric_guidance.nodes.target_selector:main',
            'pressure_controller = fabric_guidance.nodes.pressure_controller:main',
            'plc_output = fabric_guidance.nodes.plc_output:main',
            'mock_plc = fabric_guidance.nodes.mock_plc:main',
            'wearer_sim = fabric_guidance.nodes.wearer_sim:main',
            'micromanipulator_sim = fabric_guidance.nodes.micromanipulator_sim:main',
            'bag_recorder = fabric_guidance.nodes.bag_recorder:main',
            'headset_display = fabric_guidance.nodes.headset_display:main',
        ],
    },
)
