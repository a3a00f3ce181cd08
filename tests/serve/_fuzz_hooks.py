"""schemathesis hooks of tests/serve/test_fuzz.py: the server's own rule for errors."""

import json

import schemathesis


@schemathesis.check
def json_errors(ctx, response, case):
    """Every 4xx is the server's JSON error, {"error": {"code", "message"}} with a message."""
    if 400 <= response.status_code < 500:
        try:
            body = json.loads(response.text)
        except ValueError:
            raise AssertionError(f"{response.status_code} is not JSON: {response.text[:200]!r}") from None
        err = body.get("error") if isinstance(body, dict) else None
        if not (isinstance(err, dict) and err.get("code") and err.get("message") and set(body) == {"error"}):
            raise AssertionError(f"{response.status_code} is not an mptrack error: {response.text[:200]!r}")
