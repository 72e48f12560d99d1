"""The console's pages: small HTML shells that the gateway renders; `static/console.js` fills
them from the JSON API and keeps them live over server-sent events.

No inline script or style (the Content-Security-Policy forbids them): what a page's script
needs to know travels in `data-` attributes of its body.
"""

from __future__ import annotations

from collections.abc import Sequence
from html import escape

from gateway.console.auth import Identity, Via


def page(
    title: str,
    body: str,
    *,
    who: Identity | None,
    buses: Sequence[str],
    data: dict[str, str],
    scripts: Sequence[str] = (),
) -> str:
    attributes = " ".join(f'data-{k}="{escape(v)}"' for k, v in data.items())
    monitor_links = _links(who, buses)
    user = _user(who)
    extra = "".join(f'<script src="/static/{escape(s)}"></script>' for s in scripts)
    return f"""<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{escape(title)} · invt-gateway</title>
<link rel="icon" href="/favicon.ico">
<link rel="stylesheet" href="/static/console.css">
<link rel="stylesheet" href="/static/uPlot.min.css">
{extra}
<script src="/static/console.js" defer></script>
</head>
<body {attributes}>
<header>
  <a class="brand" href="/">invt-gateway</a>
  <nav><a href="/">Overview</a>{monitor_links}</nav>
  <div class="user">{user}</div>
  <span id="zone" class="zone"></span>
</header>
<main>
{body}
</main>
<div id="toast" role="status" hidden></div>
</body>
</html>
"""


def _links(who: Identity | None, buses: Sequence[str]) -> str:
    """The header's links after Overview: every page, a monitor per bus, and the configuration
    for those who may change it."""
    links = (
        '<a href="/events">Events</a><a href="/history">History</a>'
        '<a href="/diagnostics">Diagnostics</a>'
    ) + "".join(f'<a href="/monitor/{escape(bus)}">Monitor {escape(bus)}</a>' for bus in buses)
    if who is not None and who.may_configure:
        links += '<a href="/configuration">Configuration</a>'
    return links


def _user(who: Identity | None) -> str:
    """Who is logged in, with a way out; or a way in."""
    if who is None or who.via is Via.ANONYMOUS:
        user = '<a id="login-link" href="/login">Log in</a>'
        if who is not None:
            user = f'<span class="who">viewing anonymously</span> {user}'
        return user
    return (
        f'<span class="who" id="who">{escape(who.name)} ({escape(str(who.role))})</span>'
        ' <button id="logout" type="button" class="link">Log out</button>'
    )


OVERVIEW = """
<h1>Overview <span id="live" class="live">connecting…</span></h1>
<p id="store-banner" class="banner" role="alert" hidden></p>
<p id="role-banner" class="banner" hidden></p>
<section>
<h2>Buses</h2>
<div class="scroll"><table id="buses" class="grid cards">
<thead><tr><th>Bus</th><th>State</th><th>Port</th><th>Format</th><th>Utilisation</th>
<th>Planned (polls)</th><th>Transactions/s</th><th>Timeouts/min</th><th>Bad replies/min</th>
<th>Retries/min</th><th>Queue</th><th></th></tr></thead>
<tbody></tbody>
</table></div>
</section>
<section>
<h2>Drives</h2>
<div class="scroll"><table id="drives" class="grid cards">
<thead><tr><th>Drive</th><th>Unit id</th><th>Bus / address</th><th>Model</th><th>Online</th>
<th>State</th><th>Fault</th><th>Output frequency</th><th>Current</th><th>Line use</th>
<th>Last answer</th></tr>
</thead>
<tbody></tbody>
</table></div>
</section>
<section>
<h2>Events <a class="more" href="/events">all events, filters, CSV</a></h2>
<div class="scroll"><table id="events" class="grid cards small">
<thead><tr><th>Time</th><th>Event</th><th>Drive / bus</th><th>What</th><th>Who</th>
<th>Result</th></tr></thead>
<tbody></tbody>
</table></div>
</section>
"""

DRIVE = """
<h1><span id="drive-name"></span> <span id="drive-badge" class="badge"></span>
<span id="live" class="live">connecting…</span></h1>
<p id="drive-info" class="muted"></p>
<div class="columns">
<section class="values">
<h2>Live values</h2>
<table id="values" class="kv"><tbody></tbody></table>
</section>
<section class="controls" id="controls">
<h2>Commands</h2>
<p id="controls-note" class="muted"></p>
<div class="buttons">
<button type="button" data-command="run_forward">Run forward</button>
<button type="button" data-command="run_reverse">Run reverse</button>
<button type="button" data-command="stop">Stop</button>
<button type="button" data-command="coast_stop">Coast stop</button>
<button type="button" data-command="fault_reset">Fault reset</button>
</div>
<form id="setpoint-form">
<label>Set-point <input id="setpoint" type="number" step="0.01" min="0" max="600"> Hz</label>
<button type="submit">Set</button>
</form>
</section>
</div>
<section>
<h2>Last 15 minutes
<a class="more" id="history-link" href="/history">any value, up to 7 days</a></h2>
<div class="charts">
<div class="chart" id="chart-frequency"></div>
<div class="chart" id="chart-current"></div>
<div class="chart" id="chart-voltage"></div>
</div>
</section>
<section>
<h2>Fault history</h2>
<div class="columns">
<div class="scroll"><table id="fault-history" class="grid cards small"><thead><tr>
<th>Parameter</th><th>Fault</th><th>Meaning</th></tr></thead><tbody></tbody></table></div>
<div class="scroll"><table id="drive-events" class="grid cards small"><thead><tr>
<th>Time</th><th>Event</th><th>What</th><th>Who</th><th>Result</th></tr></thead><tbody></tbody></table></div>
</div>
<h3>Recorded by the gateway</h3>
<div class="scroll"><table id="recorded-faults" class="grid cards small"><thead><tr>
<th>Raised</th><th>Cleared</th><th>Duration</th><th>Fault</th><th>Hz</th><th>A</th><th>Bus V</th>
</tr></thead>
<tbody></tbody></table></div>
</section>
<section>
<h2>Parameters</h2>
<form id="parameter-find" class="filters">
<label>Find <input id="parameter-find-text" autocomplete="off"
 placeholder="P00.03, 0003H or words of the name"></label>
<button type="submit" id="parameter-find-go">Find</button>
<span id="parameter-found" class="muted"></span>
</form>
<div id="groups" class="tabs"></div>
<div class="scroll"><table id="parameters" class="grid cards small"><thead><tr>
<th>Parameter</th><th>Address</th><th>Meaning</th><th>Value</th><th>Default</th><th>Range</th>
<th>Raw</th><th></th></tr></thead><tbody></tbody></table></div>
</section>
<dialog id="confirm">
<form method="dialog">
<p id="confirm-text"></p>
<label id="confirm-ram-label"><input type="checkbox" id="confirm-ram"> RAM only (not kept
through a power cycle; no EEPROM wear)</label>
<label id="confirm-value-label">Value <input id="confirm-value" autocomplete="off"></label>
<menu><button value="cancel" type="submit">Cancel</button>
<button value="ok" id="confirm-ok" type="submit">Confirm</button></menu>
</form>
</dialog>
"""

MONITOR = """
<h1>Traffic on <span id="bus-name"></span> <span id="live" class="live">connecting…</span></h1>
<form id="filters" class="filters">
<label>Drive <select id="f-drive"><option value="">all</option></select></label>
<label>Function <select id="f-function"><option value="">all</option></select></label>
<label>Outcome <select id="f-outcome"><option value="">all</option><option>ok</option>
<option>exception</option><option>timeout</option><option>bad reply</option>
<option>retry</option></select></label>
<label><input type="checkbox" id="f-hex"> hex</label>
<button type="button" id="pause">Pause</button>
<button type="button" id="clear">Clear</button>
<button type="button" id="download-text">Download text</button>
<button type="button" id="download-csv">Download CSV</button>
<span id="count" class="muted"></span>
</form>
<div class="scroll"><table id="traffic" class="grid small mono">
<thead><tr><th>Time</th><th>Who asked</th><th>Unit / addr</th><th>Fn</th><th>Meaning</th>
<th>Outcome</th><th>Latency</th></tr></thead>
<tbody></tbody>
</table></div>
<div class="pager" id="pager" hidden>
<button type="button" id="page-newer">← Newer</button>
<span id="page-place" class="muted"></span>
<button type="button" id="page-older">Older →</button>
</div>
"""

LOGIN = """
<h1>Log in</h1>
<form id="login-form" class="login">
<label>Name <input id="login-name" name="name" autocomplete="username" required></label>
<label>Password <input id="login-password" name="password" type="password"
 autocomplete="current-password" required></label>
<button type="submit" id="login-submit">Log in</button>
<p id="login-error" class="error" role="alert"></p>
</form>
"""

EVENTS = """
<h1>Events <span id="live" class="live">loading…</span></h1>
<form id="event-filters" class="filters">
<label>Event <select id="e-kind"><option value="">all</option></select></label>
<label>Drive <select id="e-drive"><option value="">all</option></select></label>
<label>From <input id="e-since" class="when" placeholder="YYYY-MM-DD HH:MM"></label>
<label>To <input id="e-until" class="when" placeholder="YYYY-MM-DD HH:MM"></label>
<label>Rows <select id="e-limit"><option>100</option><option selected>500</option>
<option>2000</option></select></label>
<button type="button" id="e-clear">Clear filters</button>
<a id="e-csv" class="button" href="/api/events?format=csv" download="events.csv">Download CSV</a>
<span id="e-count" class="muted"></span>
</form>
<div class="scroll"><table id="all-events" class="grid cards small">
<thead><tr><th>Time</th><th>Event</th><th>Drive / bus</th><th>What</th><th>Who</th>
<th>Result</th></tr></thead>
<tbody></tbody>
</table></div>
"""

DIAGNOSTICS = """
<h1>Diagnostics <span id="live" class="live">loading…</span></h1>
<div id="buses-diagnostics"></div>
<section>
<h2>Modbus-TCP clients</h2>
<div class="scroll"><table id="tcp-clients" class="grid cards small">
<thead><tr><th>Address</th><th>Connected since</th><th>Requests</th><th>Errors</th>
<th>In flight</th><th>TLS role</th></tr></thead>
<tbody></tbody>
</table></div>
</section>
<section>
<h2>MQTT session</h2>
<table id="mqtt-session" class="kv"><tbody></tbody></table>
</section>
<section>
<h2>OPC UA sessions <span id="opcua-count" class="muted"></span></h2>
<div class="scroll"><table id="opcua-sessions" class="grid cards small">
<thead><tr><th>User</th><th>Role</th><th>Since</th></tr></thead>
<tbody></tbody>
</table></div>
</section>
<section>
<h2>Log</h2>
<form id="log-filter" class="filters">
<label>Level <select id="log-level" name="level">
<option value="debug">debug</option><option value="info" selected>info</option>
<option value="warning">warning</option><option value="error">error</option>
</select></label>
<span id="log-count" class="muted"></span>
</form>
<div class="scroll"><table id="log-lines" class="grid cards small">
<thead><tr><th>Time</th><th>Level</th><th>Logger</th><th>Message</th></tr></thead>
<tbody></tbody>
</table></div>
</section>
<section id="running-config" hidden>
<h2>Running configuration</h2>
<p class="muted">As the gateway runs now (after the last reload), defaults filled in, secrets
masked. Operators only.</p>
<pre id="config-text" class="scroll mono"></pre>
</section>
"""
