"""The network runtime: one robot per process over Zenoh (:mod:`swarmloc.net.process`, the driver, in parts), the
entry points of a node's and the belief server's processes (:mod:`swarmloc.net.entry`), the belief server
(:mod:`swarmloc.net.server`), the team launcher (:mod:`swarmloc.net.team`), the wire schema
(:mod:`swarmloc.net.schema`), fault injection (:mod:`swarmloc.net.faults`) and ROS 2 output
(:mod:`swarmloc.net.ros`). Zenoh and rosbags are imported only when a session or a bag is opened. Sources by spec,
metrics and reports are the evaluation's (:mod:`swarmloc.experiments.team`), above this package."""
