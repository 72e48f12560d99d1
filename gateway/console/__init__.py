"""The operator's console: pages, a JSON API and a traffic monitor, served by the gateway itself.

- `feature`: `ConsoleFeature`, the one place the application wires it in (start/stop).
- `web`, `pages`, `static/`: aiohttp's server, the HTML shells, the script and styles.
- `auth`, `passwords`: users, sessions, CSRF, API tokens, rate-limited logins, hashes.
- `live`: bus figures and drive state, charts; `events`: the event store interface.
- `operations`: reads and writes for a drive under Modbus-TCP's policy.
- `traffic`, `decode`: the traffic monitor and a transaction in INVT's words.
"""
