"""dVRK bridge: shipped policies on a da Vinci Research Kit's arms through the dVRK's own software, over CRTK
commands carried by its socket streamer (UDP and JSON, no ROS): :mod:`.link` (the wire and its log), :mod:`.arm`
(an arm's and the system's commands), :mod:`.seat` (a single-arm policy at the env's 50 Hz, with its safety stops)
and :mod:`.dry_run` (the same seat against the environment's own arm, sending nothing). ``dvrl-marl robot`` runs
them; ``docs/robot.md`` is the page.
"""

from dvrl_marl.dvrk.arm import ArmLink, Measured, SystemLink
from dvrl_marl.dvrk.dry_run import EchoLink
from dvrl_marl.dvrk.link import MAX_DATAGRAM, DatagramLog, ReplayLink, StreamerLink, read_log
from dvrl_marl.dvrk.seat import RobotSeat, RunSummary, SceneRobotSeat

__all__ = ["ArmLink", "SystemLink", "Measured", "StreamerLink", "ReplayLink", "EchoLink", "DatagramLog", "read_log",
           "MAX_DATAGRAM", "RobotSeat", "SceneRobotSeat", "RunSummary"]
