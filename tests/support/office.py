"""The office mission's states, actions and constants, as the learning core's tests name them.

Imports only the standard library, numpy and ``app.learning``: these tests also run in a
virtualenv with nothing else installed.
"""

from __future__ import annotations

from app.learning import Action, ActionKind, Polarity, office_mission, space_for

MISSION = office_mission()
S = space_for(MISSION)
OBS, END, ENGAGED = S.OBSERVE, S.END, S.ENGAGED
INITIATE, PASS = S.INITIATE, S.PASS
G = 0.9  # the office mission's discount
VMAX = 60.0  # the bound on values, R_max / (1 - G) (docs/method.md)
POS, NEG, NEU = Polarity.POSITIVE, Polarity.NEGATIVE, Polarity.NEUTRAL
DRINK, INFO, TEA = "ProvideDrink", "BriefInformation", "tea"
TK = S.type_known_state(DRINK)
DK = S.detail_known_state(DRINK, TEA)
REQ = S.request_state(DRINK)


def act(kind: ActionKind, service: str | None = None, detail: str | None = None) -> int:
    """The index of an action of the office mission."""
    return S.action_index(Action(kind, service, detail))


QUERY_TYPE = act(ActionKind.QUERY_TYPE)
RESPOND = act(ActionKind.RESPOND, DRINK)
INFER_DRINK = act(ActionKind.INFER_TYPE, DRINK)
INFER_TEA = act(ActionKind.INFER_DETAIL, DRINK, TEA)
PERFORM_TEA = act(ActionKind.PERFORM, DRINK, TEA)
