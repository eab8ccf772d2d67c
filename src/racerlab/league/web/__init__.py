"""The league on the web: pages for people, a JSON API for scripts and `racerlab league` commands, live boards.

    >>> from racerlab.league.web import create_app
    >>> app = create_app("club")                 # a FastAPI app on the league folder `club` (see `league serve`)

Parts: `app` (the factory, the security middleware: host check, body limits, headers), `auth` (who asks: session
cookies with CSRF tokens for browsers, `Authorization: Bearer` API tokens for scripts), `api` (JSON under /api),
`pages` (server-rendered HTML: Jinja2 templates with autoescaping), `manage` (the pages that change races,
people and one's account), `forms` (reading and checking form fields),
`live` (server-sent events of a race's board), `server` (`serve`: uvicorn, TLS, local workers).
Every route asks `auth` who asks before it reads; the service layer (`racerlab.league.League`) checks the role
again. See docs/league.md.
"""

from racerlab.league.web.app import create_app

__all__ = ["create_app"]
