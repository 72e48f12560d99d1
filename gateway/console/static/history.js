// invt-gateway console: the history page. Any polled value of a drive over a chosen window,
// from /api/drives/NAME/history: one chart per value, zoomed by dragging across one (all
// follow), and a CSV file of what is shown. Uses console.js's helpers (api, el, clock, stamp).
"use strict";

const HISTORY_COLORS = ["#2563eb", "#d97706", "#059669", "#7c3aed", "#dc2626", "#0891b2"];
const HISTORY_HEIGHT = 170;
const HISTORY_DEFAULT_KEYS = ["output_frequency_hz", "output_current_a"];
// Time between ticks, in whole seconds: the values are a second apart at the finest, and a
// tick between two seconds would repeat its neighbour's label.
const HISTORY_TICKS = [1, 2, 5, 10, 15, 30, 60, 120, 300, 600, 900, 1800, 3600, 7200, 10800,
  21600, 43200, 86400, 2 * 86400, 7 * 86400];

function historyPage() {
  const params = new URLSearchParams(location.search);
  const drives = (document.body.dataset.drives || "").split(",").filter(Boolean);
  const driveSelect = document.getElementById("h-drive");
  const windowSelect = document.getElementById("h-window");
  const keysBox = document.getElementById("h-keys");
  const chartsBox = document.getElementById("h-charts");
  const csv = document.getElementById("h-csv");
  const reset = document.getElementById("h-reset");
  const count = document.getElementById("h-count");
  const live = document.getElementById("live");
  for (const name of drives) driveSelect.append(el("option", { value: name }, name));
  driveSelect.value = params.get("drive") || document.body.dataset.drive || drives[0] || "";
  if (params.get("window")) windowSelect.value = params.get("window");
  let chosen = (params.get("keys") || "").split(",").filter(Boolean);
  let data = null;
  // [since, until] in epoch seconds while zoomed in; a stretch kept in the address opens zoomed.
  const seconds = (text) => (text ? Date.parse(text) / 1000 : NaN);
  let zoom = [seconds(params.get("since")), seconds(params.get("until"))];
  if (!(zoom[0] < zoom[1])) zoom = null;
  let plots = [];

  const query = (format) => {
    const q = new URLSearchParams({ keys: chosen.join(","), points: "800" });
    if (zoom) {
      q.set("since", new Date(zoom[0] * 1000).toISOString());
      q.set("until", new Date(zoom[1] * 1000).toISOString());
    } else {
      q.set("window", windowSelect.value);
    }
    if (format) q.set("format", format);
    return `/api/drives/${encodeURIComponent(driveSelect.value)}/history?${q}`;
  };

  const remember = () => {
    const q = new URLSearchParams({ drive: driveSelect.value, window: windowSelect.value });
    if (chosen.length) q.set("keys", chosen.join(","));
    if (zoom) {
      q.set("since", new Date(zoom[0] * 1000).toISOString());
      q.set("until", new Date(zoom[1] * 1000).toISOString());
    }
    history.replaceState(null, "", `/history?${q}`);
    csv.href = query("csv");
    reset.disabled = !zoom;
  };

  const drawKeys = (available) => {
    keysBox.replaceChildren(...available.map((key) => {
      const box = el("input", { type: "checkbox", value: key, checked: chosen.includes(key) });
      box.addEventListener("change", () => {
        chosen = Array.from(keysBox.querySelectorAll("input:checked")).map((i) => i.value);
        load();
      });
      return el("label", { class: "key" }, box, ` ${key}`);
    }));
  };

  const zoomAll = (since, until) => {
    zoom = [since, until];
    load();
  };

  const draw = () => {
    plots.forEach((plot) => plot.destroy());
    plots = [];
    chartsBox.replaceChildren();
    const times = data.columns[0];
    // The x axis spans the points; for one point alone uPlot would pick a day after it (and
    // label it in years): then it spans the window asked for, a minute at least.
    const [since, until] = [seconds(data.since), seconds(data.until)];
    const middle = (since + until) / 2;
    const span = until - since >= 60 ? [since, until] : [middle - 30, middle + 30];
    const xRange = (u, min, max) => (times.length > 1 ? [min, max] : span);
    data.keys.slice(1).forEach((key, index) => {
      const column = data.columns[index + 1];
      if (column.some((v) => typeof v === "string")) return; // a text value: in the CSV only
      const box = el("div", { class: "chart", "data-key": key });
      chartsBox.append(box);
      const options = {
        title: key, width: box.clientWidth || 360, height: HISTORY_HEIGHT,
        scales: { x: { time: true, range: xRange } },
        series: [{}, { label: key, stroke: HISTORY_COLORS[index % HISTORY_COLORS.length], width: 2 }],
        axes: [
          { space: 80, incrs: HISTORY_TICKS, values: (u, ticks, axis, space, step) => {
            const labels = ticks.map((tick) => (step >= 86400 ? stamp(tick).slice(0, 10) : clock(new Date(tick * 1000), step < 60)));
            box.dataset.xLabels = labels.join(" "); // what the axis says, for a test to read
            return labels;
          } },
          { size: 60 },
        ],
        legend: { show: false },
        cursor: { drag: { x: true, y: false, setScale: false } },
        hooks: {
          setSelect: [(u) => {
            if (u.select.width < 5) return;
            const since = u.posToVal(u.select.left, "x");
            const until = u.posToVal(u.select.left + u.select.width, "x");
            if (until > since) zoomAll(since, until);
          }],
        },
      };
      const plot = new uPlot(options, [times, column], box);
      new ResizeObserver(() => {
        const width = box.clientWidth;
        if (width && Math.abs(width - plot.width) > 1) plot.setSize({ width, height: HISTORY_HEIGHT });
      }).observe(box);
      plots.push(plot);
    });
    if (!plots.length) chartsBox.append(el("p", { class: "muted" }, "Choose a value to chart."));
  };

  async function load() {
    remember();
    live.textContent = "loading…";
    live.className = "live";
    try {
      const answer = await api(query());
      data = answer;
      if (!chosen.length) {
        chosen = HISTORY_DEFAULT_KEYS.filter((k) => answer.available.includes(k));
        if (!chosen.length) chosen = answer.available.slice(0, 1);
        if (chosen.length) return load();
      }
      drawKeys(answer.available);
      draw();
      const points = answer.columns[0].length;
      const step = answer.step_s >= 60 ? `${Math.round(answer.step_s / 60)} min` : `${answer.step_s} s`;
      count.textContent = `${points} point${points === 1 ? "" : "s"}, one per ${step}, from ${stamp(answer.since)} to ` +
        `${stamp(answer.until)} (${answer.source === "live" ? "live, last 15 minutes" : "the store's history"})`;
      live.textContent = answer.source === "live" ? "live" : "history";
      live.className = "live on";
      remember();
    } catch (e) {
      live.textContent = e.message;
      live.className = "live off";
    }
    return undefined;
  }

  driveSelect.addEventListener("change", () => { chosen = []; zoom = null; load(); });
  windowSelect.addEventListener("change", () => { zoom = null; load(); });
  reset.addEventListener("click", () => { zoom = null; load(); });
  load();
  // The live window follows the clock.
  setInterval(() => { if (!zoom && windowSelect.value === "15m") load(); }, 5000);
}

document.addEventListener("DOMContentLoaded", () => {
  if (document.body.dataset.page === "history") historyPage();
});
