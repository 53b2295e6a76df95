"""User administration (admins only): add, re-role, re-password, remove; the audit log."""

from __future__ import annotations

import asyncio

from fastapi import APIRouter, Request
from fastapi.responses import RedirectResponse, Response

from blackbox.station.auth import Role, StationAuthError
from blackbox.station.web.context import WebContext


def router(web: WebContext) -> APIRouter:
    routes = APIRouter()
    auth = web.auth

    @routes.get("/users")
    async def users(request: Request) -> Response:
        session = web.require(request, Role.ADMIN)
        return web.page(request, "users.html", session, users=auth.users(),
                        audit=auth.audit_log(limit=100), nav="users", message="")

    @routes.post("/users")
    async def users_change(request: Request) -> Response:
        session, form, target = await web.change(request, "user.change", Role.ADMIN)
        op, name = form.get("op", ""), form.get("name", "")[:64]
        by, where = session.user.name, web.address(request)
        try:
            if op == "add":
                await asyncio.to_thread(auth.add_user, name, form.get("password", ""),
                                        Role.parse(form.get("role", "")), by=by,
                                        address=where)
            elif op == "role":
                auth.set_role(name, Role.parse(form.get("role", "")), by=by, address=where)
            elif op == "password":
                await asyncio.to_thread(auth.set_password, name, form.get("password", ""),
                                        by=by, address=where)
            elif op == "remove":
                if name == by:
                    raise StationAuthError("you cannot remove yourself")
                auth.remove_user(name, by=by, address=where)
            else:
                raise StationAuthError(f"unknown operation {op[:20]!r}")
        except (StationAuthError, ValueError) as exc:
            auth.audit(by, f"user.{op[:20]}", target, "refused", where, str(exc))
            return web.page(request, "users.html", session, users=auth.users(), status=400,
                            audit=auth.audit_log(limit=100), nav="users", message=str(exc))
        return RedirectResponse("/users", status_code=303)

    return routes
