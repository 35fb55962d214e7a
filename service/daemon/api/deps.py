"""Shared dependencies: the rig of the running app, and the bearer scheme the OpenAPI document declares.

The token itself is checked by :class:`WebGuard` before any body is read; the dependency here
checks it again (cheap) so a route is safe even if mounted without the middleware, and so the
OpenAPI document shows which routes need it.
"""

from __future__ import annotations

from fastapi import Depends, Request, Security
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from graytrack.service.daemon.errors import DaemonError
from graytrack.service.daemon.rig import Rig
from graytrack.service.daemon.api.security import token_matches

scheme = HTTPBearer(auto_error=False, description="the token from the config or DATA/token")


class Unauthorized(DaemonError):
    status = 401


def rig(request: Request) -> Rig:
    return request.app.state.rig


def require_token(request: Request, credentials: HTTPAuthorizationCredentials | None = Security(scheme)) -> None:
    if credentials is None or not credentials.credentials:
        raise Unauthorized("missing bearer token: send 'Authorization: Bearer <token>'")
    if not token_matches(credentials.credentials, request.app.state.policy.token):
        raise Unauthorized("invalid bearer token")


AUTHORIZED = [Depends(require_token)]
