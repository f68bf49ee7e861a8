"""ROS arguments, names and parameters as rcl reads them (swarmloc.ros.args, swarmloc.ros.params): name validation
and expansion (ROS 2 design article "Topic and Service names"), remapping rules, ``--ros-args`` parsing, params
files with node sections and wildcards, and one clear error per bad parameter."""

from __future__ import annotations

import pytest
import yaml

from swarmloc.ros.args import RosArgsError, check_name, expand, parse_ros_args
from swarmloc.ros.params import ParamsError, RosParams, defaults_yaml, load_params

pytestmark = pytest.mark.unit


@pytest.mark.parametrize("name", ["odom", "/robot1/odom", "~", "~/odom", "a/b_c/d2", "_x"])
def test_valid_names(name):
    assert check_name(name) == name


@pytest.mark.parametrize("name", ["", "1odom", "/a//b", "a/", "a__b", "a/~", "a b", "odom-1", "/~x"])
def test_invalid_names_are_refused_with_the_name(name):
    with pytest.raises(RosArgsError):
        check_name(name)


def test_expansion_of_absolute_relative_and_private_names():
    assert expand("odom", "/robot1", "swarmloc") == "/robot1/odom"
    assert expand("/odom", "/robot1", "swarmloc") == "/odom"
    assert expand("~/status", "/robot1", "swarmloc") == "/robot1/swarmloc/status"
    assert expand("~", "/", "swarmloc") == "/swarmloc"
    assert expand("odom", "/", "n") == "/odom"


def test_ros_args_remaps_params_and_files():
    ros, rest = parse_ros_args(["ros", "--max-wall", "3", "--ros-args", "-r", "__ns:=/robot1", "-r", "odom:=wheel/odom",
                                "-r", "other:pose:=/x", "-p", "robot_id:=1", "-p", "motion.q_v0:=0.002",
                                "--params-file", "a.yaml", "--", "tail"])  # fmt: skip
    assert rest == ["ros", "--max-wall", "3", "tail"]
    assert ros.namespace == "/robot1" and ros.params == {"robot_id": 1, "motion.q_v0": 0.002}
    assert ros.params_files == ["a.yaml"]
    assert ros.resolve("odom", "/robot1", "swarmloc") == "/robot1/wheel/odom"
    assert ros.resolve("pose", "/robot1", "swarmloc") == "/robot1/pose"  # the rule is for node "other" only
    assert ros.resolve("pose", "/robot1", "other") == "/x"
    assert ros.resolve("/robot1/odom", "/robot1", "swarmloc") == "/robot1/wheel/odom"  # matched when expanded


@pytest.mark.parametrize(
    "argv",
    [
        ["--ros-args", "-r", "odom"],
        ["--ros-args", "-p"],
        ["--ros-args", "-x", "a:=b"],
        ["--ros-args", "-r", "__ns:=robot1"],
        ["--ros-args", "-r", "odom:=1bad"],
    ],
)
def test_bad_ros_args_are_refused(argv):
    with pytest.raises(RosArgsError):
        parse_ros_args(argv)


def test_params_file_sections_wildcards_and_overrides(tmp_path):
    f = tmp_path / "team.yaml"
    f.write_text(
        yaml.safe_dump(
            {
                "/**": {
                    "ros__parameters": {
                        "team": "lab",
                        "team_robots": [0, 1, 2],
                        "frequency": 20.0,
                        "motion": {"q_v0": 0.001},
                    }
                },
                "/robot1/swarmloc": {
                    "ros__parameters": {"robot_id": 1, "sensor_mounts": {"robot1/camera": [0.1, 0, 0]}}
                },
                "/robot2/swarmloc": {"ros__parameters": {"robot_id": 2}},
            }
        )
    )
    p = load_params([str(f)], {"frequency": 5}, "swarmloc", "/robot1")
    assert (p.robot_id, p.team, p.frequency, p.team_ids) == (1, "lab", 5.0, [0, 1, 2])
    assert p.config().motion.q_v0 == 0.001 and p.sensor_mounts == {"robot1/camera": [0.1, 0.0, 0.0]}
    assert load_params([str(f)], {}, "swarmloc", "/robot2").robot_id == 2


@pytest.mark.parametrize(("override", "needle"), [
    ({"frequency": 0}, "frequency"), ({"frequncy": 3}, "unknown parameter frequncy"),
    ({"estimator": "kalman"}, "estimator"), ({"initial_state": [0, 0]}, "initial_state"),
    ({"motion.q_v0": -1}, "q_v0"), ({"initial_covariance": [1, 2, 3, 4]}, "initial_covariance"),
    ({"key_file": "k"}, "key_file and roster_file"), ({"landmarks": {"l7": [0, 0]}}, "landmark<N>"),
    ({"initial_state": [0, 0, float("nan")]}, "finite"),
])  # fmt: skip
def test_each_bad_parameter_is_named(override, needle):
    with pytest.raises(ParamsError, match=needle):
        load_params([], override)


def test_bad_params_files(tmp_path):
    (tmp_path / "a.yaml").write_text("robot1: {x: 1}\n")
    (tmp_path / "b.yaml").write_text(": : :\n")
    with pytest.raises(ParamsError, match="ros__parameters"):
        load_params([str(tmp_path / "a.yaml")], {})
    with pytest.raises(ParamsError, match="YAML"):
        load_params([str(tmp_path / "b.yaml")], {})
    (tmp_path / "c.yaml").write_text("garbage: [\n")
    with pytest.raises(ParamsError, match=r"c.yaml: not a YAML file: .*line 2, column 1$") as exc:
        load_params([str(tmp_path / "c.yaml")], {})
    assert "\n" not in str(exc.value) and "^" not in str(exc.value)  # PyYAML's message, with its caret, on one line
    with pytest.raises(ParamsError, match="cannot read"):
        load_params([str(tmp_path / "missing.yaml")], {})


def test_the_defaults_listing_is_every_parameter_and_reads_back():
    text = defaults_yaml("swarmloc")
    got = yaml.safe_load(text)["swarmloc"]["ros__parameters"]
    assert list(got) == [f for f in RosParams.__struct_fields__]
    assert load_params([], got) == RosParams()
    assert text.count("    # ") == len(got) and "    # \n" not in text  # every parameter has its meaning


def test_the_shipped_example_params_and_launch_lines_load_for_every_robot():
    import ast
    from pathlib import Path

    here = Path(__file__).resolve().parents[1] / "examples" / "ros2"
    launch = (here / "team.launch.py").read_text()
    ast.parse(launch)
    for r in range(3):
        argv = ["ros", "--ros-args", "--params-file", str(here / "team.yaml"), "-r", f"__ns:=/robot{r}",
                "-r", "odom:=wheel/odom", "-r", "detections:=camera/detections"]  # fmt: skip
        ros, rest = parse_ros_args(argv)
        assert rest == ["ros"]
        p = load_params(ros.params_files, ros.params, "swarmloc", ros.namespace)
        assert (p.robot_id, p.team_ids, p.estimator) == (r, [0, 1, 2], "diekf")
        assert p.base_link_frame == f"robot{r}/base_link"
        assert ros.resolve(p.odom_topic, ros.namespace, "swarmloc") == f"/robot{r}/wheel/odom"
        assert ros.resolve(p.odometry_topic, ros.namespace, "swarmloc") == f"/robot{r}/odometry/filtered"
    assert '"odom:=wheel/odom"' in launch and '"detections:=camera/detections"' in launch
