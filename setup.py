"""ament_python package robotino_geom_mpc (see README.md)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "robotino_geom_mpc"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*", "robotino_sim_node"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.xml")
         + glob("config/*.rviz") + glob("config/*.json")),  # the presets, DDS profiles, RViz and Foxglove views
        (f"share/{PACKAGE}/urdf", glob("urdf/*.urdf")),
    ],
    python_requires=">=3.10",
    install_requires=[  # what the package imports (package.xml: the same through rosdep keys)
        "setuptools",
        "numpy>=1.26,<3",
        "scipy>=1.11,<2",
        "PyYAML>=6.0,<7",
        "matplotlib>=3.8,<4",
        "tqdm>=4.66,<5",
        "threadpoolctl>=3.1,<4",  # BLAS on one thread in the nodes and the study's workers
        "mcap>=1.2,<2",  # the recorder's writer and the bag reader (zstd chunks)
        "zstandard>=0.22,<1",
        "rosbags>=0.10,<0.12",  # the bags' message definitions and QoS metadata, the report's fallback decoder
    ],
    extras_require={
        "ros": [
            "ros-jazzy-rclpy==7.1.6",
            "ros-jazzy-rmw-fastrtps-cpp==8.4.3",
            "ros-jazzy-common-interfaces==5.3.6",
            "ros-jazzy-rosgraph-msgs==2.0.3",
        ],
        "cluster": ["dask[distributed]>=2024.8"],  # study/tune --scheduler: batches on a Dask cluster
        "tune": ["optuna>=5,<6"],  # the tune verb's sampler (TPE), pruning and trial storage
        "constrained": ["daqp>=0.11,<1"],  # control.mode constrained (imported when a constrained controller is built)
        "bench": ["osqp>=1.0,<2", "daqp>=0.11,<1", "quadprog>=0.1.11,<0.2"],  # the QP solvers compared side by side
        "viz": [
            "foxglove-sdk>=0.30,<0.31",  # run --foxglove: the live view's WebSocket server
        ],
        "test": [
            "pytest>=8,<10",
            "pytest-xdist>=3.6,<4",  # make test: two workers (the ROS tests mostly wait on their processes)
            "websockets>=15,<16",  # the live view test's Foxglove WebSocket client
            "hypothesis>=6.100,<7",
            "colcon-common-extensions==0.3.0",
            "mcap-ros2-support>=0.5,<1",  # an independent reader of the bags
            "osqp>=1.0,<2",
            "daqp>=0.11,<1",
            "quadprog>=0.1.11,<0.2",  # a second QP solver as the truth
            "ruff==0.17.6",
            "mypy==2.4.1",
            "import-linter==2.17",
        ],
        "docs": ["sphinx>=8,<10", "myst-parser>=4,<6", "sphinx-book-theme==1.4.0"],  # the theme: docs/conf.py
    },
    zip_safe=True,
    maintainer="robotino_geom_mpc developers",
    maintainer_email="robotino-geom-mpc@example.org",
    description="Geometric decoupling plus decoupled MPC for the Festo Robotino (ROS 2 Jazzy).",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "robotino-geom-mpc = robotino_geom_mpc.cli:main",
            "plant_node = robotino_sim_node.plant_node:main",
            "controller_node = robotino_geom_mpc.nodes.controller_node:main",
            "trajectory_node = robotino_geom_mpc.nodes.trajectory_node:main",
            "recorder_node = robotino_geom_mpc.recording.recorder_node:main",
            "robot_description_publisher = robotino_geom_mpc.nodes.robot_description_node:main",
            "command_buffer_node = robotino_geom_mpc.nodes.command_buffer_node:main",
            "live_view_node = robotino_geom_mpc.recording.live_view_node:main",
            "fleet_plant_node = robotino_sim_node.fleet_plant_node:main",
            "fleet_controller_node = robotino_geom_mpc.nodes.fleet_controller_node:main",
            "fleet_trajectory_node = robotino_geom_mpc.nodes.fleet_trajectory_node:main",
        ],
    },
)
