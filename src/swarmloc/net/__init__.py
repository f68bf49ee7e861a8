"""The network runtime: one robot per process over Zenoh (:mod:`swarmloc.net.process`), the belief server
(:mod:`swarmloc.net.server`), the team launcher (:mod:`swarmloc.net.team`), the wire schema
(:mod:`swarmloc.net.schema`), fault injection (:mod:`swarmloc.net.faults`) and ROS 2 output
(:mod:`swarmloc.net.ros`). Zenoh and rosbags are imported only when a session or a bag is opened."""
