from __future__ import annotations

from fastapi import APIRouter
from sqlalchemy.orm import Session

from app.api.deps import CurrentPrincipal, TransactionalRoute
from app.api.errors import responses
from app.schemas.audit import AuditList
from app.services import audit as service

from ._common import Limit, SeqCursor

router = APIRouter(prefix="/v1/admin", tags=["admin"], route_class=TransactionalRoute)


@router.get("/audit", response_model=AuditList, responses=responses(403))
def list_audit(
    session: Session, principal: CurrentPrincipal,
    limit: Limit = 50,
    cursor: SeqCursor = None,
) -> AuditList:
    """The audit log of admin actions of every fleet, newest first (admin): who (the key),
    what (user.delete, model.reset, model.export, model.import, model.rebuild, key.create,
    key.revoke), when."""
    return service.list_audit(session, principal, limit=limit, cursor=cursor)
