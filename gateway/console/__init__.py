"""The operator's console: pages, a JSON API and a traffic monitor, served by the gateway itself.

- `feature`: `ConsoleFeature`, the one place the application wires it in (start/stop).
- `web`, `pages`, `static/`: aiohttp's routes, the pages and the API, the HTML shells, the
  script and styles; `context`: what every handler reaches; `guard`: who asks and what they may
  do, before any handler; `login`: logging in and out; `streams`: the live server-sent events.
- `auth`, `passwords`: users, sessions, CSRF, API tokens, rate-limited logins, hashes.
- `live`: bus figures and drive state, charts; `events`: the event store interface.
- `operations`: reads and writes for a drive under Modbus-TCP's policy.
- `traffic`, `decode`: the traffic monitor and a transaction in INVT's words.
"""
