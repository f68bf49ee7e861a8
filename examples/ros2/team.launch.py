"""A ROS 2 launch description for a three-robot swarmloc team on one machine (``ros2 launch team.launch.py``):
one ``swarmloc ros`` process per robot, in its namespace, with the robot's wheel odometry remapped onto the node's
``odom`` input. swarmloc is a Python package, not an ament package, so each node is an ``ExecuteProcess``."""

from pathlib import Path

from launch import LaunchDescription
from launch.actions import ExecuteProcess

PARAMS = str(Path(__file__).with_name("team.yaml"))


def generate_launch_description() -> LaunchDescription:
    nodes = [
        ExecuteProcess(
            cmd=["swarmloc", "ros", "--ros-args", "--params-file", PARAMS, "-r", f"__ns:=/robot{r}",
                 "-r", "odom:=wheel/odom", "-r", "detections:=camera/detections"],
            name=f"swarmloc_robot{r}", output="screen",
        )  # fmt: skip
        for r in range(3)
    ]
    return LaunchDescription(nodes)
