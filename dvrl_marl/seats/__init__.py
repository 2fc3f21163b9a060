"""One seat of the collaborative scene as a Gymnasium environment (``dvrl_marl/SurgeonSeat-v8``), its partner inside:
:class:`~dvrl_marl.seats.seat_env.SeatEnv` and its batched form (:mod:`dvrl_marl.seats.seat_vector`). A partner may be
a script, the learned pipeline or a shipped policy, so seats build on agents, pipelines and policies."""

from dvrl_marl.seats.seat_env import PARTNERS, SeatEnv

__all__ = ["SeatEnv", "PARTNERS"]
