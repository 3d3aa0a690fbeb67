"""The client's calls for a fleet's prior against the real application, in-process, on SQLite
and PostgreSQL: reading and switching the fleet's prior, keeping a person out of it, and the
model saying what it started from."""

from __future__ import annotations

import attune_client as a
import httpx
import pytest
from fastapi import FastAPI

from tests.support.fixtures import MakeKey

from .conftest import BASE_URL, fast

pytestmark = pytest.mark.anyio


async def test_switch_the_fleets_prior_and_keep_a_person_out(
    robot: a.AsyncClient, app: FastAPI, make_key: MakeKey
) -> None:
    staff = a.AsyncClient(BASE_URL, make_key("staff"), transport=httpx.ASGITransport(app=app))
    fast(staff)
    async with staff:
        prior = await staff.fleet_prior("default")
        assert isinstance(prior, a.FleetPrior)
        assert prior.enabled is True
        assert prior.in_force == []  # nobody to average yet
        off = await staff.set_fleet_prior("default", enabled=False)
        assert off.enabled is False
        assert (await staff.fleet_prior("default")).updated_by is not None
        with pytest.raises(a.PermissionDeniedError):
            await robot.set_fleet_prior("default", enabled=True)
        with pytest.raises(a.PermissionDeniedError):
            await staff.fleet_prior("other")
        user = await robot.put_user("lin", fleet_prior=False)
        assert user.fleet_prior is False
        assert (await staff.put_user("lin", display_name="Mrs. Lin")).fleet_prior is False
        assert (await staff.put_user("lin", fleet_prior=True)).fleet_prior is True
        with pytest.raises(a.PermissionDeniedError):  # what staff set, a robot cannot undo
            await robot.put_user("lin", fleet_prior=False)
    model = await robot.get_model("lin")
    assert model.started_from == a.StartedFrom(kind="fresh", contributors=None)
