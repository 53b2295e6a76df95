"""Log-in and log-out: the only pages open without a session."""

from __future__ import annotations

import asyncio
import hmac
import secrets

from fastapi import APIRouter, Request
from fastapi.responses import RedirectResponse, Response

from blackbox.station.auth import Role
from blackbox.station.passwords import MAX_PASSWORD
from blackbox.station.web.context import LOGIN_COOKIE, SESSION_COOKIE, WebContext, safe_next


def router(web: WebContext) -> APIRouter:
    routes = APIRouter()
    auth, settings = web.auth, web.settings

    def login_page(request: Request, message: str = "", status: int = 200,
                   next_url: str = "/") -> Response:
        token = secrets.token_urlsafe(24)
        response = web.page(request, "login.html", None, status=status, login_token=token,
                            message=message, next_url=next_url)
        response.set_cookie(LOGIN_COOKIE, token, httponly=True, samesite="strict",
                            secure=settings.secure_cookies, max_age=1800, path="/login")
        return response

    @routes.get("/login")
    async def login_form(request: Request, next: str = "/") -> Response:
        if web.session_of(request) is not None:
            return RedirectResponse(safe_next(next), status_code=303)
        return login_page(request, next_url=safe_next(next))

    @routes.post("/login")
    async def login(request: Request) -> Response:
        form = {k: v for k, v in (await request.form()).items() if isinstance(v, str)}
        cookie = request.cookies.get(LOGIN_COOKIE, "")
        if not cookie or not hmac.compare_digest(cookie, form.get("login_token", "")):
            auth.audit(form.get("username", "")[:64], "login", "", "refused",
                       web.address(request), "missing or wrong CSRF token")
            return login_page(request, "The log-in form expired; please try again.", 403)
        name = form.get("username", "")[:64]
        result = await asyncio.to_thread(auth.log_in, name,
                                         form.get("password", "")[:MAX_PASSWORD + 1],
                                         web.address(request))
        next_url = safe_next(form.get("next"))
        if result.retry_after > 0:
            response = login_page(request, "Too many failed log-ins. Try again in "
                                  f"{result.retry_after:.0f} s.", 429, next_url)
            response.headers["Retry-After"] = str(int(result.retry_after) + 1)
            return response
        if result.session_token is None:
            return login_page(request, "Wrong user name or password.", 401, next_url)
        response = RedirectResponse(next_url, status_code=303)
        response.set_cookie(SESSION_COOKIE, result.session_token, httponly=True,
                            samesite="strict", secure=settings.secure_cookies, path="/",
                            max_age=int(auth.policy.max_age))
        response.delete_cookie(LOGIN_COOKIE, path="/login")
        return response

    @routes.post("/logout")
    async def logout(request: Request) -> Response:
        await web.change(request, "logout", Role.VIEWER)
        auth.log_out(request.cookies.get(SESSION_COOKIE, ""), web.address(request))
        response = RedirectResponse("/login", status_code=303)
        response.delete_cookie(SESSION_COOKIE, path="/")
        return response

    return routes
