"""The floor of the HTTP stack for ``mptrack bench --suite serve``: an ASGI callable that answers every
request 200 with an empty body, served by the same uvicorn as ``mptrack serve``."""


async def app(scope, receive, send):
    if scope["type"] != "http":
        return
    await send({"type": "http.response.start", "status": 200, "headers": [(b"content-length", b"0")]})
    await send({"type": "http.response.body", "body": b""})
