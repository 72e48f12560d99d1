// invt-gateway console: plain JavaScript, no build step. Each page's body says which page it is
// (data-page); everything shown comes from the JSON API, live parts from server-sent events.
"use strict";

const body = document.body;
const session = { csrf: null, mayWrite: false, user: null };

function el(tag, attrs, ...children) {
  const node = document.createElement(tag);
  for (const [key, value] of Object.entries(attrs || {})) {
    if (value === null || value === undefined || value === false) continue;
    if (key === "class") node.className = value;
    else if (key.startsWith("data-")) node.setAttribute(key, value);
    else node[key] = value;
  }
  for (const child of children) {
    if (child === null || child === undefined) continue;
    node.append(child instanceof Node ? child : document.createTextNode(String(child)));
  }
  return node;
}

function fmt(value, decimals, unit) {
  if (value === null || value === undefined) return "–";
  const number = typeof value === "number" ? value.toFixed(decimals) : String(value);
  return unit ? `${number} ${unit}` : number;
}

// One time format everywhere: the ISO date and the 24-hour clock, in this browser's time zone,
// which the header names. The gateway sends UTC (ISO 8601 with Z); files downloaded keep that.
function pad(number, width) { return String(number).padStart(width || 2, "0"); }

function clock(date, seconds) {
  const time = `${pad(date.getHours())}:${pad(date.getMinutes())}`;
  return seconds ? `${time}:${pad(date.getSeconds())}` : time;
}

function stamp(value, milliseconds) {
  if (value === null || value === undefined || value === "") return "–";
  const date = typeof value === "number" ? new Date(value * 1000) : new Date(value);
  if (Number.isNaN(date.getTime())) return String(value);
  const day = `${date.getFullYear()}-${pad(date.getMonth() + 1)}-${pad(date.getDate())}`;
  return `${day} ${clock(date, true)}${milliseconds ? `.${pad(date.getMilliseconds(), 3)}` : ""}`;
}

function zoneName() {
  const minutes = -new Date().getTimezoneOffset();
  const offset = `UTC${minutes < 0 ? "-" : "+"}${pad(Math.floor(Math.abs(minutes) / 60))}:` +
    pad(Math.abs(minutes) % 60);
  const name = Intl.DateTimeFormat().resolvedOptions().timeZone;
  return name && name !== "UTC" ? `${name} (${offset})` : offset;
}

function timeCell(value, milliseconds) {
  return el("td", { class: "time" }, stamp(value, milliseconds));
}

function toast(text, kind) {
  const box = document.getElementById("toast");
  box.textContent = text;
  box.className = kind || "";
  box.hidden = false;
  clearTimeout(toast.timer);
  toast.timer = setTimeout(() => { box.hidden = true; }, 6000);
}

async function api(path, options) {
  const init = Object.assign({ credentials: "same-origin", headers: {} }, options || {});
  if (init.json !== undefined) {
    init.method = init.method || "POST";
    init.body = JSON.stringify(init.json);
    init.headers["Content-Type"] = "application/json";
    if (session.csrf) init.headers["X-CSRF-Token"] = session.csrf;
  }
  const response = await fetch(path, init);
  let data = null;
  try { data = await response.json(); } catch (e) { data = null; }
  if (!response.ok) {
    const message = (data && data.error) || `${response.status} ${response.statusText}`;
    const error = new Error(message);
    error.status = response.status;
    error.detail = data;
    throw error;
  }
  return data;
}

function stream(path, handlers) {
  const live = document.getElementById("live");
  const source = new EventSource(path);
  source.onopen = () => { if (live) { live.textContent = "live"; live.className = "live on"; } };
  source.onerror = () => { if (live) { live.textContent = "reconnecting…"; live.className = "live off"; } };
  for (const [name, handler] of Object.entries(handlers)) {
    source.addEventListener(name, (event) => handler(JSON.parse(event.data)));
  }
  return source;
}

async function loadSession() {
  try {
    const info = await api("/api/session");
    session.csrf = info.csrf_token;
    session.mayWrite = info.may_write;
    session.user = info.user;
    session.role = info.role;
    session.commandsEnabled = info.commands_enabled;
  } catch (e) { /* the login page has no session */ }
  const logout = document.getElementById("logout");
  if (logout) {
    logout.addEventListener("click", async () => {
      await api("/api/logout", { json: {} });
      location.href = "/login";
    });
  }
}

// -- overview ------------------------------------------------------------------------------

function stateClass(drive) {
  if (drive.online === false) return "offline";
  if (drive.fault_name && drive.fault_name !== "none") return "fault";
  if (drive.state && drive.state.startsWith("running")) return "running";
  return "stopped";
}

function busRow(bus) {
  return el("tr", { "data-bus": bus.name },
    el("td", {}, bus.name),
    el("td", {}, el("span", { class: `badge ${bus.state}` }, bus.state)),
    el("td", { class: "mono" }, bus.port),
    el("td", {}, bus.format),
    el("td", { class: "utilisation num" }, fmt(bus.utilisation * 100, 1, "%")),
    // Past the poll budget: little of the line is left for SCADA (check-config warns too).
    el("td", { class: `planned num${bus.over_budget ? " warn" : ""}` },
      fmt(bus.planned_utilisation * 100, 1, "%")),
    el("td", {}, fmt(bus.transactions_per_s, 1)),
    el("td", { class: bus.timeouts_per_min ? "warn" : "" }, bus.timeouts_per_min),
    el("td", { class: bus.bad_replies_per_min ? "warn" : "" }, bus.bad_replies_per_min),
    el("td", {}, bus.retries_per_min),
    el("td", {}, bus.queue_depth),
    el("td", {}, el("a", { href: `/monitor/${encodeURIComponent(bus.name)}` }, "traffic")));
}

function driveRow(drive) {
  const online = drive.online === null ? "–" : (drive.online ? "online" : "offline");
  // fault_description holds the short code already: "OH2: inverter module overheat".
  const fault = drive.fault_name && drive.fault_name !== "none" ? drive.fault_description : "none";
  return el("tr", { "data-drive": drive.name, class: stateClass(drive) },
    el("td", {}, el("a", { href: `/drives/${encodeURIComponent(drive.name)}` }, drive.name)),
    el("td", {}, drive.unit_id),
    el("td", {}, `${drive.bus} / ${drive.address}`),
    el("td", {}, drive.model),
    el("td", { class: "online" }, el("span", { class: `badge ${online}` }, online)),
    el("td", { class: "state" }, drive.state || "–"),
    el("td", { class: "fault" }, fault),
    el("td", { class: "frequency num" }, fmt(drive.output_frequency_hz, 2, "Hz")),
    el("td", { class: "current num" }, fmt(drive.output_current_a, 1, "A")),
    // What it took of its line lately (polls, SCADA, MQTT) beside what its polls were planned to.
    el("td", { class: "line num" }, `${fmt(drive.utilisation * 100, 1, "%")} ` +
      `(planned ${fmt(drive.planned_utilisation * 100, 1, "%")})`),
    timeCell(drive.last_answer));
}

function eventWhat(event) {
  // "write (control)", "modbus writes", "login failed (authentication)"
  const kind = (event.type === "modbus_writes" ? "Modbus-TCP write" : event.kind).replace(/_/g, " ");
  const category = event.category ? ` (${event.category})` : "";
  return `${kind}${category}${event.pending ? " · this minute" : ""}`;
}

function eventWho(event) {
  const who = event.user ? `${event.user}${event.who && event.who.startsWith("console") ? " (console)" : ""}` : event.who;
  return event.address && who !== event.address ? `${who || "?"} from ${event.address}` : (who || "");
}

function eventRow(event, withDrive) {
  const cells = [timeCell(event.time), el("td", {}, eventWhat(event))];
  if (withDrive) cells.push(el("td", {}, event.drive || event.bus || ""));
  cells.push(el("td", {}, event.text), el("td", {}, eventWho(event)),
    el("td", { class: event.result && event.result !== "ok" ? "warn" : "" }, event.result || ""));
  return el("tr", { class: `event ${event.kind}`, "data-id": event.id }, ...cells);
}

function fill(tableId, rows, empty) {
  const tbody = document.querySelector(`#${tableId} tbody`);
  const headings = [...document.querySelectorAll(`#${tableId} thead th`)].map((th) => th.textContent);
  if (!rows.length && empty) {
    rows = [el("tr", {}, el("td", { colSpan: headings.length, class: "muted" }, empty))];
  }
  // Each cell knows its column's name: on a phone a row is a card of "name value" lines.
  for (const row of rows) {
    [...row.cells].forEach((cell, i) => { if (cell.colSpan === 1 && headings[i]) cell.dataset.label = headings[i]; });
  }
  tbody.replaceChildren(...rows);
}

function roleText(r) {
  // "Standby box gw-b (peer gw-a 10.0.0.11): listening only, never transmitting · since ..."
  const peer = r.peer ? ` (peer ${r.peer})` : "";
  const role = { active: "Active", listening: "Listening (asked to be active)", standby: "Standby" }[r.role] || r.role;
  const change = r.last_change ? ` · ${r.last_change.reason}, ${r.last_change.at}` : "";
  const foreign = r.foreign_frames ? ` · another master heard ${r.foreign_frames}×` : "";
  const config = r.peer_config && r.peer_config.count ? ` · ${peerConfigText(r.peer_config)}` : "";
  // Why this box can't be the line's master or hold the virtual address (its adapter, a cut).
  const unfit = r.unfit ? ` · unfit: ${r.unfit}` : "";
  return `${role} box ${r.box}${peer}${change} · takeovers ${r.takeovers}${foreign}${config}${unfit}`;
}

function peerConfigText(p) {
  // "box gw-a runs another configuration: buses[line1].timeout_ms (since ...)"
  const more = p.count > p.differs.length ? ` and ${p.count - p.differs.length} more` : "";
  return `box ${p.peer} runs another configuration: ${p.differs.join(", ")}${more} (since ${p.since})`;
}

function overviewPage() {
  const refreshEvents = async () => {
    const data = await api("/api/events?limit=50");
    fill("events", data.events.map((e) => eventRow(e, true)), "no events since the gateway started");
  };
  stream("/api/live", {
    overview: (data) => {
      const banner = document.getElementById("store-banner");
      banner.hidden = !data.store_problem;
      banner.textContent = data.store_problem ? `Events are not kept on disk: ${data.store_problem}` : "";
      const role = document.getElementById("role-banner");
      role.hidden = !data.redundancy;
      role.textContent = data.redundancy ? roleText(data.redundancy) : "";
      fill("buses", data.buses.map(busRow));
      fill("drives", data.drives.map(driveRow));
    },
  });
  refreshEvents();
  setInterval(refreshEvents, 2000);
}

// -- a drive's page --------------------------------------------------------------------------

const VALUE_ROWS = [
  ["state", "State", (v) => (v || "–").replace(/_/g, " ")],
  ["fault_name", "Fault", (v, t) => (v && v !== "none" ? t.fault_description : "none")],
  ["output_frequency_hz", "Output frequency", (v) => fmt(v, 2, "Hz")],
  ["set_frequency_hz", "Set frequency", (v) => fmt(v, 2, "Hz")],
  ["output_current_a", "Output current", (v) => fmt(v, 1, "A")],
  ["bus_voltage_v", "Bus voltage", (v) => fmt(v, 1, "V")],
  ["output_voltage_v", "Output voltage", (v) => fmt(v, 0, "V")],
  ["rotation_speed_rpm", "Rotation speed", (v) => fmt(v, 0, "rpm")],
  ["output_power_pct", "Output power", (v) => fmt(v, 1, "%")],
  ["output_torque_pct", "Output torque", (v) => fmt(v, 1, "%")],
  ["command_source", "Command source", (v) => v || "–"],
  ["ready", "Ready", (v) => (v === undefined ? "–" : (v ? "yes" : "no"))],
  ["last_seen", "Last answer", (v) => stamp(v)],
];

const CHARTS = [
  ["chart-frequency", 1, "Output frequency", "Hz", "#2563eb"],
  ["chart-current", 2, "Output current", "A", "#d97706"],
  ["chart-voltage", 3, "Bus voltage", "V", "#059669"],
];

const CHART_HEIGHT = 180;

function makeCharts(columns) {
  return CHARTS.map(([id, index, label, unit, color]) => {
    const box = document.getElementById(id);
    const options = {
      title: `${label} (${unit})`, width: box.clientWidth || 360, height: CHART_HEIGHT,
      scales: { x: { time: true } },
      series: [{}, { label, stroke: color, width: 2, spanGaps: false }],
      // The 24-hour clock as everywhere else (uPlot's own labels are 12-hour), far enough apart
      // that two labels never overlap: seconds only when ticks are less than a minute apart.
      axes: [
        { space: 80, values: (u, ticks, axis, space, step) =>
          ticks.map((tick) => clock(new Date(tick * 1000), step < 60)) },
        { size: 50 },
      ],
      legend: { show: false },
    };
    const plot = new uPlot(options, [columns[0], columns[index]], box);
    // The chart follows its box (a window resized, a phone turned), not the width at load.
    new ResizeObserver(() => {
      const width = box.clientWidth;
      if (width && Math.abs(width - plot.width) > 1) plot.setSize({ width, height: CHART_HEIGHT });
    }).observe(box);
    return { plot, index };
  });
}

function drivePage() {
  const name = body.dataset.drive;
  document.getElementById("drive-name").textContent = name;
  document.getElementById("history-link").href = `/history?drive=${encodeURIComponent(name)}`;
  let columns = [[], [], [], []];
  let charts = null;
  let lastPoint = 0;

  api(`/api/drives/${encodeURIComponent(name)}/chart`).then((data) => {
    columns = data.columns;
    lastPoint = columns[0].length ? columns[0][columns[0].length - 1] : 0;
    charts = makeCharts(columns);
  });

  const show = (drive) => {
    const t = drive.telemetry || {};
    const badge = document.getElementById("drive-badge");
    const online = drive.online === null ? "unknown" : (drive.online ? "online" : "offline");
    badge.textContent = online;
    badge.className = `badge ${online}`;
    document.getElementById("drive-info").textContent =
      `unit id ${drive.unit_id} · ${drive.bus} address ${drive.address} · ${drive.model}`;
    const rows = VALUE_ROWS.filter(([key]) => key in t || key === "state").map(([key, label, show]) =>
      el("tr", { "data-key": key }, el("th", {}, label), el("td", {}, show(t[key], t))));
    fill("values", rows);
    const now = Date.now() / 1000;
    if (charts && drive.online && now - lastPoint >= 1) {
      lastPoint = now;
      columns[0].push(now);
      columns[1].push(t.output_frequency_hz ?? null);
      columns[2].push(t.output_current_a ?? null);
      columns[3].push(t.bus_voltage_v ?? null);
      while (columns[0].length && now - columns[0][0] > 900) columns.forEach((c) => c.shift());
      charts.forEach(({ plot, index }) => plot.setData([columns[0], columns[index]]));
    }
  };
  stream(`/api/live?drive=${encodeURIComponent(name)}`, { drive: show });

  setupControls(name);
  loadFaults(name);
  setInterval(() => loadFaults(name), 10000);
  setupParameters(name);
}

async function loadFaults(name) {
  try {
    const data = await api(`/api/drives/${encodeURIComponent(name)}/faults?limit=30`);
    fill("fault-history", data.fault_history.map((f) =>
      el("tr", { class: f.code ? "fault" : "" }, el("td", {}, f.parameter),
        el("td", {}, f.code ? String(f.code) : "none"), el("td", {}, f.description))));
    fill("drive-events", data.events.map((e) => eventRow(e, false)), "no events recorded for this drive");
    fill("recorded-faults", (data.recorded_faults || []).map((f) => {
      const s = f.snapshot || {};
      return el("tr", { class: f.cleared ? "" : "fault" },
        timeCell(f.raised), f.cleared ? timeCell(f.cleared) : el("td", {}, "still raised"),
        el("td", {}, f.duration_s === null ? "-" : `${f.duration_s} s`),
        el("td", {}, `${f.code} ${f.name}`), el("td", {}, String(s.output_frequency_hz ?? "-")),
        el("td", {}, String(s.output_current_a ?? "-")), el("td", {}, String(s.bus_voltage_v ?? "-")));
    }), "no fault recorded for this drive");
  } catch (error) {
    fill("fault-history", [el("tr", {}, el("td", { colSpan: 3, class: "muted" },
      `fault history not readable: ${error.message}`))]);
  }
}

function confirmDialog(text, options) {
  const dialog = document.getElementById("confirm");
  document.getElementById("confirm-text").textContent = text;
  document.getElementById("confirm-ram-label").hidden = !options.ram;
  document.getElementById("confirm-ram").checked = false;
  const valueLabel = document.getElementById("confirm-value-label");
  valueLabel.hidden = options.value === undefined;
  document.getElementById("confirm-value").value = options.value ?? "";
  return new Promise((resolve) => {
    dialog.onclose = () => resolve(dialog.returnValue === "ok" ? {
      ram: document.getElementById("confirm-ram").checked,
      value: document.getElementById("confirm-value").value,
    } : null);
    dialog.returnValue = "";
    dialog.showModal();
  });
}

async function write(path, json, what) {
  try {
    const result = await api(path, { json });
    toast(`${what}: done (${result.write})`, "ok");
    return true;
  } catch (error) {
    // "P00.11 = 99999 is outside ..." names the write already: no second "P00.11 = 99999: ".
    const said = error.message.startsWith(what) ? error.message : `${what}: ${error.message}`;
    toast(said, "error");
    return false;
  }
}

function setupControls(name) {
  const controls = document.getElementById("controls");
  const note = document.getElementById("controls-note");
  const enabled = session.mayWrite;
  controls.querySelectorAll("button, input").forEach((node) => { node.disabled = !enabled; });
  if (!session.commandsEnabled) note.textContent = "Commands are disabled (console.commands_enabled: false).";
  else if (!enabled) note.textContent = "Log in as an operator to run, stop or write.";
  else note.textContent = `As ${session.user} (operator): every command asks for a confirmation.`;
  const base = `/api/drives/${encodeURIComponent(name)}`;
  controls.querySelectorAll("button[data-command]").forEach((button) => {
    button.addEventListener("click", async () => {
      const command = button.dataset.command;
      const label = button.textContent;
      if (!(await confirmDialog(`${label} ${name}?`, {}))) return;
      await write(`${base}/command`, { command }, `${label} ${name}`);
    });
  });
  document.getElementById("setpoint-form").addEventListener("submit", async (event) => {
    event.preventDefault();
    const hz = parseFloat(document.getElementById("setpoint").value);
    if (Number.isNaN(hz)) { toast("Set-point: type a frequency in Hz", "error"); return; }
    if (!(await confirmDialog(`Set ${name}'s set-point to ${hz.toFixed(2)} Hz?`, {}))) return;
    await write(`${base}/frequency`, { hz }, `Set-point ${hz.toFixed(2)} Hz`);
  });
}

function setupParameters(name) {
  const groups = body.dataset.groups.split(",");
  const tabs = document.getElementById("groups");
  const found = document.getElementById("parameter-found");
  const columns = 8;
  const note = (text, kind = "muted") =>
    fill("parameters", [el("tr", {}, el("td", { colSpan: columns, class: kind }, text))]);
  const row = (p, reload) => {
    const edit = p.writable && session.mayWrite
      ? el("button", { type: "button", class: "small", onclick: () => editParameter(name, p, reload) }, "Write…")
      : null;
    // Whether the value is the factory's: "depends on model" defaults can't say.
    const differs = p.differs_from_default === true;
    const fallback = p.default === null && p.range !== undefined && p.writable ? "depends on model" : "–";
    const meaning = p.confirmed === false ? `${p.description} (unconfirmed for this series)` : p.description;
    return el("tr", { class: differs ? "differs" : "", "data-name": p.name },
      el("td", {}, p.name), el("td", { class: "mono" }, p.address),
      el("td", {}, meaning),
      el("td", { class: "num" }, p.value ?? "–", differs ? el("span", { class: "badge warn", title: "differs from the default" }, "≠ default") : null),
      el("td", { class: "num" }, p.default ?? fallback),
      el("td", {}, p.range ?? "–", p.change ? el("span", { class: "muted" }, ` (${p.change})`) : null),
      el("td", { class: "mono" }, p.raw === null ? "–" : p.raw), el("td", {}, edit));
  };
  const load = async (group) => {
    found.textContent = "";
    tabs.querySelectorAll("button").forEach((b) => b.classList.toggle("active", b.dataset.group === group));
    note(`reading ${group}…`);
    try {
      const data = await api(`/api/drives/${encodeURIComponent(name)}/parameters?group=${group}`);
      if (!data.parameters.length) { note(`the profile names no parameter of ${group}`); return; }
      fill("parameters", data.parameters.map((p) => row(p, () => load(group))));
    } catch (error) {
      note(error.message, "warn");
    }
  };
  const find = async (text) => {
    tabs.querySelectorAll("button").forEach((b) => b.classList.remove("active"));
    note(`finding ${text}…`);
    try {
      const data = await api(`/api/drives/${encodeURIComponent(name)}/parameters?find=${encodeURIComponent(text)}`);
      found.textContent = `${data.parameters.length} found`;
      if (!data.parameters.length) { note(`no parameter of ${name} is ${text} or named so`); return; }
      fill("parameters", data.parameters.map((p) => row(p, () => find(text))));
    } catch (error) {
      note(error.message, "warn");
    }
  };
  document.getElementById("parameter-find").addEventListener("submit", (event) => {
    event.preventDefault();
    const text = document.getElementById("parameter-find-text").value.trim();
    if (text) find(text);
  });
  for (const group of groups) {
    tabs.append(el("button", { type: "button", "data-group": group, onclick: () => load(group) }, group));
  }
  load(groups[0]);
}

async function editParameter(name, parameter, reload) {
  const current = parameter.value ? String(parameter.value).split(" ")[0] : "";
  const answer = await confirmDialog(
    `Write ${parameter.name} (${parameter.description}) of ${name}${parameter.unit ? ` in ${parameter.unit}` : ""}:`,
    { ram: parameter.name.startsWith("P"), value: current });
  if (!answer) return;
  const ok = await write(`/api/drives/${encodeURIComponent(name)}/parameter`,
    { name: parameter.name, value: answer.value, ram: answer.ram },
    `${parameter.name} = ${answer.value}${answer.ram ? " (RAM only)" : ""}`);
  if (ok) reload();
}

// -- the traffic monitor ---------------------------------------------------------------------

// An attempt's time, split: in the queue, bytes on the wire, the drive's own answer delay.
function latencyCell(r) {
  const part = (label, ms) => (ms === null || ms === undefined ? null : `${label} ${ms}`);
  const parts = [part("queue", r.queue_ms), part("wire", r.wire_ms), part("drive", r.turnaround_ms)]
    .filter(Boolean);
  return el("td", { class: "num latency" }, `${r.latency_ms} ms`,
    parts.length ? el("div", { class: "split" }, `${parts.join(" · ")} ms`) : null);
}

function monitorPage() {
  const bus = body.dataset.bus;
  document.getElementById("bus-name").textContent = bus;
  const rows = [];
  const MAX_ROWS = 2000;
  let paused = false;
  const held = [];
  const tbody = document.querySelector("#traffic tbody");
  const filters = {
    drive: document.getElementById("f-drive"),
    fn: document.getElementById("f-function"),
    outcome: document.getElementById("f-outcome"),
    hex: document.getElementById("f-hex"),
  };
  const seenDrives = new Set();
  const seenFunctions = new Set();

  const matches = (r) => {
    if (filters.drive.value && String(r.drive ?? r.address) !== filters.drive.value) return false;
    if (filters.fn.value && r.function !== filters.fn.value) return false;
    const outcome = filters.outcome.value;
    if (outcome === "retry" && !r.attempt) return false;
    if (outcome === "bad reply" && !/bad reply|crc/.test(r.outcome)) return false;
    if (outcome && outcome !== "retry" && outcome !== "bad reply" && !r.outcome.includes(outcome)) return false;
    return true;
  };
  const outcomeClass = (r) => (r.outcome.endsWith("ok") || r.outcome.endsWith("broadcast") ? "ok" : "bad");
  const rowOf = (r) => {
    const meaning = el("td", { class: "meaning" }, r.meaning);
    if (filters.hex.checked) {
      meaning.append(el("div", { class: "hex" }, `→ ${r.request_hex}`),
        el("div", { class: "hex" }, `← ${r.reply_hex || "(nothing)"}`));
    }
    return el("tr", { "data-seq": r.seq, class: outcomeClass(r) },
      timeCell(r.time, true), el("td", {}, r.client),
      el("td", {}, `${r.unit_id ?? "–"} / ${r.address}${r.drive ? ` ${r.drive}` : ""}`),
      el("td", {}, r.function), meaning,
      el("td", { class: "outcome" }, r.outcome), latencyCell(r));
  };
  const shown = () => rows.filter(matches);
  // A page of rows, newest first: 50 on a phone (a row is a card there, ~120 px tall), 500
  // on a wider screen. `pageEnd` null follows the line; otherwise the page ends at that
  // row (its seq), and stays put while new rows arrive.
  const narrow = window.matchMedia("(max-width: 700px)");
  const pageSize = () => (narrow.matches ? 50 : 500);
  let pageEnd = null;
  let page = { start: 0, end: 0, visible: [] };
  const pager = {
    box: document.getElementById("pager"), place: document.getElementById("page-place"),
    newer: document.getElementById("page-newer"), older: document.getElementById("page-older"),
  };
  const render = () => {
    const visible = shown();
    const size = pageSize();
    let end = visible.length;
    if (pageEnd !== null) end = visible.filter((r) => r.seq <= pageEnd).length;
    const start = Math.max(0, end - size);
    page = { start, end, visible };
    tbody.replaceChildren(...visible.slice(start, end).reverse().map(rowOf));
    document.getElementById("count").textContent =
      `${visible.length} shown of ${rows.length}${paused ? ` · paused (${held.length} waiting)` : ""}`;
    pager.box.hidden = visible.length <= size && pageEnd === null;
    pager.place.textContent = end > start
      ? `rows ${visible.length - end + 1} to ${visible.length - start} of ${visible.length}, newest first`
      : "no row here";
    pager.newer.disabled = pageEnd === null;
    pager.older.disabled = start === 0;
  };
  pager.older.addEventListener("click", () => {
    if (page.start > 0) pageEnd = page.visible[page.start - 1].seq;
    render();
    document.getElementById("traffic").scrollIntoView();
  });
  pager.newer.addEventListener("click", () => {
    const end = page.end + pageSize();
    pageEnd = end >= page.visible.length ? null : page.visible[end - 1].seq;
    render();
    document.getElementById("traffic").scrollIntoView();
  });
  narrow.addEventListener("change", () => render());
  const addOption = (select, seen, value, label) => {
    if (value === null || value === undefined || seen.has(value)) return;
    seen.add(value);
    select.append(el("option", { value }, label));
  };
  const take = (r) => {
    rows.push(r);
    if (rows.length > MAX_ROWS) rows.shift();
    addOption(filters.drive, seenDrives, String(r.drive ?? r.address), r.drive ?? `address ${r.address}`);
    addOption(filters.fn, seenFunctions, r.function, r.function);
  };
  let pending = false;
  const schedule = () => {
    if (pending) return;
    pending = true;
    requestAnimationFrame(() => { pending = false; render(); });
  };
  stream(`/api/buses/${encodeURIComponent(bus)}/traffic?recent=2000`, {
    traffic: (r) => {
      if (paused) { held.push(r); } else { take(r); }
      schedule();
    },
  });
  Object.values(filters).forEach((f) => f.addEventListener("change", () => { pageEnd = null; render(); }));
  document.getElementById("pause").addEventListener("click", (event) => {
    paused = !paused;
    event.target.textContent = paused ? "Resume" : "Pause";
    if (!paused) held.splice(0).forEach(take);
    render();
  });
  document.getElementById("clear").addEventListener("click", () => { rows.length = 0; pageEnd = null; render(); });
  const download = (name, type, text) => {
    const link = el("a", { href: URL.createObjectURL(new Blob([text], { type })), download: name });
    document.body.append(link);
    link.click();
    link.remove();
  };
  const columns = ["time", "client", "unit_id", "address", "drive", "function", "meaning",
    "outcome", "latency_ms", "queue_ms", "wire_ms", "turnaround_ms", "request_hex", "reply_hex"];
  document.getElementById("download-csv").addEventListener("click", () => {
    // OWASP's rule, as the server's exports (gateway/console/spreadsheet.py): text that a
    // spreadsheet would run as a formula gets a quote in front; numbers stay numbers.
    const safe = (v) => (typeof v === "string" && /^[=+\-@\t\r]/.test(v) ? `'${v}` : String(v ?? ""));
    const quote = (v) => `"${safe(v).replace(/"/g, '""')}"`;
    const lines = [columns.join(",")].concat(shown().map((r) => columns.map((c) => quote(r[c])).join(",")));
    download(`traffic-${bus}.csv`, "text/csv", lines.join("\r\n") + "\r\n");
  });
  document.getElementById("download-text").addEventListener("click", () => {
    const lines = shown().map((r) =>
      `${r.time}  ${r.client.padEnd(22)} unit ${String(r.unit_id ?? "-").padStart(3)}  ${r.function}  ` +
      `${r.meaning}  [${r.outcome}, ${r.latency_ms} ms: queue ${r.queue_ms}, wire ${r.wire_ms}, ` +
      `drive ${r.turnaround_ms ?? "–"} ms]` +
      (filters.hex.checked ? `\n    → ${r.request_hex}\n    ← ${r.reply_hex}` : ""));
    download(`traffic-${bus}.txt`, "text/plain", lines.join("\n") + "\n");
  });
  render();
}

// -- events ----------------------------------------------------------------------------------

const EVENT_KINDS = [
  ["write", "writes (all)"], ["command", "commands (console, MQTT)"],
  ["modbus_writes", "Modbus-TCP writes"], ["fault_raised", "fault raised"],
  ["fault_cleared", "fault cleared"], ["drive_offline", "drive offline"],
  ["drive_online", "drive online"], ["port_lost", "port lost"], ["port_back", "port back"],
  ["login", "login"], ["login_failed", "failed login"], ["logout", "logout"],
  ["config_reloaded", "configuration reloaded"], ["config_changed", "configuration edited"],
];

function parseStamp(text) {
  // "2026-11-25 06:00" (seconds optional, a date alone is its midnight), as the tables write
  // times: this browser's zone. Null when it is not one; undefined when empty.
  if (!text.trim()) return undefined;
  const m = /^(\d{4})-(\d{2})-(\d{2})(?:[ T](\d{2}):(\d{2})(?::(\d{2}))?)?$/.exec(text.trim());
  if (!m) return null;
  const date = new Date(+m[1], m[2] - 1, +m[3], +(m[4] || 0), +(m[5] || 0), +(m[6] || 0));
  return Number.isNaN(date.getTime()) ? null : date;
}

function eventsPage() {
  const field = {
    kind: document.getElementById("e-kind"), drive: document.getElementById("e-drive"),
    since: document.getElementById("e-since"), until: document.getElementById("e-until"),
    limit: document.getElementById("e-limit"),
  };
  for (const [kind, label] of EVENT_KINDS) field.kind.append(el("option", { value: kind }, label));
  for (const drive of (body.dataset.drives || "").split(",").filter(Boolean)) {
    field.drive.append(el("option", { value: drive }, drive));
  }
  const asked = new URLSearchParams(location.search);
  field.kind.value = asked.get("kind") || "";
  field.drive.value = asked.get("drive") || "";
  field.since.value = asked.get("since") ? stamp(asked.get("since")) : "";
  field.until.value = asked.get("until") ? stamp(asked.get("until")) : "";
  if (asked.get("limit")) field.limit.value = asked.get("limit");
  const query = () => {
    const q = new URLSearchParams();
    if (field.kind.value) q.set("kind", field.kind.value);
    if (field.drive.value) q.set("drive", field.drive.value);
    // The fields hold this browser's local time; the API takes ISO 8601 with its zone (UTC).
    for (const key of ["since", "until"]) {
      const date = parseStamp(field[key].value);
      field[key].setCustomValidity(date === null ? "a time as 2026-11-25 06:00" : "");
      if (date === null) return null;
      if (date) q.set(key, date.toISOString());
    }
    q.set("limit", field.limit.value);
    return q;
  };
  const live = document.getElementById("live");
  const load = async () => {
    const q = query();
    if (q === null) {
      live.textContent = "a time as 2026-11-25 06:00";
      live.className = "live off";
      return;
    }
    history.replaceState(null, "", `/events?${q}`);
    const csv = new URLSearchParams(q);
    csv.set("format", "csv");
    csv.delete("limit");
    document.getElementById("e-csv").href = `/api/events?${csv}`;
    try {
      const data = await api(`/api/events?${q}`);
      fill("all-events", data.events.map((e) => eventRow(e, true)), "no event matches");
      document.getElementById("e-count").textContent =
        `${data.events.length} event${data.events.length === 1 ? "" : "s"}, newest first`;
      live.textContent = field.until.value ? "as asked" : "live";
      live.className = "live on";
    } catch (error) {
      live.textContent = error.message;
      live.className = "live off";
    }
  };
  Object.values(field).forEach((f) => f.addEventListener("change", load));
  document.getElementById("event-filters").addEventListener("submit", (event) => {
    event.preventDefault();  // Enter in a time field: apply it, stay on the page
    load();
  });
  document.getElementById("e-clear").addEventListener("click", () => {
    field.kind.value = field.drive.value = field.since.value = field.until.value = "";
    load();
  });
  load();
  setInterval(() => { if (!field.until.value) load(); }, 5000);
}

// -- diagnostics -----------------------------------------------------------------------------

const LINE_COUNTS = [
  ["sent", "Frames sent"], ["replies", "Replies"], ["timeouts", "Timeouts"],
  ["crc_errors", "CRC errors"], ["bad_replies", "Other bad replies"], ["exceptions", "Exceptions"],
  ["retries", "Retries"], ["late_replies", "Late replies"],
  ["resyncs", "Resyncs (markers)"], ["failed", "Failed requests"],
];
const TROUBLE = new Set(["timeouts", "crc_errors", "bad_replies", "exceptions", "late_replies", "resyncs", "failed"]);

function exceptionsText(list) {
  return list.length ? list.map((e) => `${e.code} ${e.name}: ${e.count}`).join(", ") : "0";
}

function countCell(key, total, minute) {
  // Since start, and the last minute under it: a counter that grows now stands out.
  const show = key === "exceptions" ? exceptionsText : String;
  const now = key === "exceptions" ? minute.length : minute;
  return el("td", { class: `num count ${TROUBLE.has(key) && now ? "warn" : ""}` },
    el("span", {}, el("span", {}, show(total)), el("span", { class: "minute" }, `${show(minute)} last min`)));
}

function countsRow(label, scope, attrs) {
  return el("tr", attrs, el("th", {}, label),
    ...LINE_COUNTS.map(([key]) => countCell(key, scope.since_start[key], scope.last_minute[key])));
}

function busDiagnostics(bus) {
  const tableId = `counts-${bus.name}`;
  const head = el("tr", {}, el("th", {}, "Bus / drive"), ...LINE_COUNTS.map(([, label]) => el("th", {}, label)));
  const section = el("section", { "data-bus": bus.name },
    el("h2", {}, `Bus ${bus.name} `, el("span", { class: `badge ${bus.state}` }, bus.state)),
    el("p", { class: "muted", "data-summary": bus.name }),
    el("p", { class: "muted", "data-line": bus.name }),
    el("div", { class: "scroll" },
      el("table", { id: tableId, class: "grid cards small diagnostics" }, el("thead", {}, head), el("tbody"))));
  return section;
}

function diagnosticsPage() {
  const holder = document.getElementById("buses-diagnostics");
  const live = document.getElementById("live");
  const show = (data) => {
    for (const bus of data.buses) {
      const id = `counts-${bus.name}`;
      if (!document.getElementById(id)) holder.append(busDiagnostics(bus));
      // Refreshed with the counters: requests, port errors and the adapter's effects grow too.
      holder.querySelector(`p[data-summary="${bus.name}"]`).textContent =
        `${bus.port} · ${bus.format} · counting since ${stamp(bus.counting_since)} · ` +
        `${bus.requests} requests, ${bus.queue_full} refused (queue full), ` +
        `${bus.coalesced} shared, ${bus.port_errors} port errors, ${bus.reopens} reopens`;
      holder.querySelector(`p[data-line="${bus.name}"]`).textContent =
        `adapter: ${bus.line.glitch_bytes} glitch bytes skipped, ${bus.line.echoes} echoes, ` +
        `longest silence inside a reply ${bus.line.longest_reply_silence_ms} ms`;
      const rows = [countsRow(`${bus.name} (all)`, bus, { class: "total" })].concat(
        bus.drives.map((d) => countsRow(d.drive ? `${d.drive} (${d.address})` : `address ${d.address}`,
          d, { "data-drive": d.drive || "" })));
      fill(id, rows);
    }
    const clients = data.modbus_tcp ? data.modbus_tcp.clients : [];
    fill("tcp-clients", clients.map((c) => el("tr", { "data-client": c.client },
      el("td", { class: "mono" }, c.address), timeCell(c.connected_since),
      el("td", { class: "num" }, c.requests), el("td", { class: `num ${c.errors ? "warn" : ""}` }, c.errors),
      el("td", { class: "num" }, c.in_flight), el("td", {}, c.tls ? (c.role || "TLS, no role") : "plain"))),
    "no Modbus-TCP client connected");
    const m = data.mqtt;
    const rows = m ? [
      ["Broker", `${m.broker}${m.tls ? " (TLS)" : ""}`],
      ["Protocol", `MQTT ${m.protocol}`],
      ["Connected", m.connected ? `yes, since ${stamp(m.connected_since)}` : "no"],
      ["Events queued", String(m.queued)],
      ["Events dropped", String(m.dropped)],
      ["Last error", m.last_error ? `${m.last_error} (${stamp(m.last_error_at)})` : "none"],
      ["Connections", `${m.connects} made, ${m.connect_failures} failed`],
      ["Published", String(m.published)],
    ] : [["MQTT", "not configured"]];
    fill("mqtt-session", rows.map(([k, v]) => el("tr", { "data-key": k }, el("th", {}, k), el("td", {}, v))));
    const sessions = data.opcua ? data.opcua.sessions : [];
    document.getElementById("opcua-count").textContent = data.opcua ? `${sessions.length} now` : "not configured";
    fill("opcua-sessions", sessions.map((s) => el("tr", { "data-user": s.user },
      el("td", {}, s.user), el("td", {}, s.role), timeCell(s.since))),
    data.opcua ? "no OPC UA session" : "OPC UA not configured");
  };
  const level = document.getElementById("log-level");
  const showLog = (data) => {
    // Newest first: what just happened is what the engineer came for.
    const lines = data.lines.slice().reverse();
    fill("log-lines", lines.map((line) => el("tr", { "data-level": line.level },
      timeCell(line.time), el("td", { class: line.level === "error" || line.level === "warning" ? "warn" : "" }, line.level),
      el("td", { class: "mono" }, line.logger), el("td", {}, line.message))),
    `no log line at ${data.level} or above yet`);
    document.getElementById("log-count").textContent = `${data.lines.length} lines`;
  };
  level.addEventListener("change", async () => showLog(await api(`/api/log?level=${level.value}`)));
  const load = async () => {
    try {
      show(await api("/api/diagnostics"));
      showLog(await api(`/api/log?level=${level.value}`));
      live.textContent = "live";
      live.className = "live on";
    } catch (error) {
      live.textContent = error.message;
      live.className = "live off";
    }
  };
  load();
  setInterval(load, 2000);
  // Operators only: a viewer's 403 leaves the section hidden.
  api("/api/config").then((data) => {
    document.getElementById("config-text").textContent = JSON.stringify(data.configuration, null, 2);
    document.getElementById("running-config").hidden = false;
  }).catch(() => {});
}

// -- login -----------------------------------------------------------------------------------

function loginPage() {
  const form = document.getElementById("login-form");
  form.addEventListener("submit", async (event) => {
    event.preventDefault();
    const error = document.getElementById("login-error");
    error.textContent = "";
    try {
      await api("/api/login", { json: {
        name: document.getElementById("login-name").value,
        password: document.getElementById("login-password").value,
      } });
      const next = new URLSearchParams(location.search).get("next");
      location.href = next && next.startsWith("/") && !next.startsWith("//") ? next : "/";
    } catch (e) {
      error.textContent = e.message;
    }
  });
}

(async () => {
  const zone = document.getElementById("zone");
  if (zone) zone.textContent = `times in ${zoneName()}`;
  await loadSession();
  const pages = {
    overview: overviewPage, drive: drivePage, monitor: monitorPage, events: eventsPage,
    diagnostics: diagnosticsPage, login: loginPage,
  };
  const start = pages[body.dataset.page];
  if (start) start();
})();
