"""Episodes: an event starts a negotiation, outcomes move it on, feedback adds to it.

``validate`` checks a request against the mission and the negotiation's rules, ``write`` runs
the robots' writes (start, outcome, feedback), ``read`` the traces and lists, and ``render``
turns stored rows into the wire's JSON.
"""

from .read import get_trace, list_episodes
from .render import action_out
from .write import Written, add_feedback, report_outcome, start_episode

__all__ = [
    "Written",
    "action_out",
    "add_feedback",
    "get_trace",
    "list_episodes",
    "report_outcome",
    "start_episode",
]
