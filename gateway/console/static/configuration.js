// invt-gateway console: the configuration page (admins only). Edit the file's text, check it
// as check-config does (each problem at its key), apply it (kept as a new version, reloaded
// live), see every version's diff and roll back to one. Uses console.js's helpers.
"use strict";

function configurationPage() {
  const text = document.getElementById("c-text");
  const note = document.getElementById("c-note");
  const result = document.getElementById("c-result");
  const live = document.getElementById("live");
  const diffBox = document.getElementById("c-diff");
  let loaded = "";
  let base = null; // the file's fingerprint: the secrets' numbers refer to it

  const say = (state, message) => {
    live.textContent = message;
    live.className = `live ${state}`;
  };

  const list = (title, items, cls) => (items && items.length
    ? el("div", { class: cls }, el("strong", {}, title), el("ul", {}, ...items.map((i) => el("li", {}, i))))
    : null);

  const showChecked = (answer, headline) => {
    const problems = (answer.problems || []).map((p) =>
      (p.line ? `line ${p.line}: ` : "") + (p.key ? `${p.key}: ${p.reason}` : p.reason));
    const parts = [
      el("p", { class: answer.ok ? "ok-text" : "error" }, headline),
      list("Problems", problems, "problems error"),
      list("Warnings", answer.warnings, "warnings warn"),
      list(answer.version ? "Applied at once" : "Would be applied at once", answer.changed, "changed"),
      list("Waits for a restart", answer.restart_needed, "restart warn"),
    ];
    result.replaceChildren(...parts.filter(Boolean));
  };

  const loadFile = async () => {
    const file = await api("/api/config/file");
    document.getElementById("c-path").textContent = `${file.path} · secrets shown as "***1", "***2"...`;
    text.value = file.text;
    loaded = file.text;
    base = file.base;
    // A file the console can't write (a read-only mount, root's file): said at once, and
    // Apply stays off rather than failing after the edit.
    document.getElementById("c-apply").disabled = Boolean(file.read_only);
    if (file.read_only) result.replaceChildren(el("p", { class: "error", id: "c-read-only" }, file.read_only));
  };

  const loadVersions = async () => {
    const { versions } = await api("/api/config/versions");
    const rows = versions.map((v, index) => {
      const show = el("button", { type: "button", class: "small", "data-show": v.id }, "Diff");
      show.addEventListener("click", () => {
        diffBox.hidden = false;
        diffBox.textContent = v.diff || "(no change)";
      });
      const back = el("button", { type: "button", class: "small", "data-rollback": v.id,
        disabled: index === 0 }, "Roll back to this");
      back.addEventListener("click", async () => {
        if (!confirm(`Apply version ${v.id} again (as a new version)?`)) return;
        try {
          const done = await api(`/api/config/versions/${v.id}/rollback`, { json: {} });
          showChecked(done, `Rolled back to version ${v.id}: now version ${done.version}. ${done.outcome.join(" ")}`);
          await loadFile();
          await loadVersions();
        } catch (e) { result.replaceChildren(el("p", { class: "error" }, e.message)); }
      });
      return el("tr", { "data-version": v.id },
        el("td", { "data-label": "Version", class: "num" }, String(v.id)),
        el("td", { "data-label": "Time", class: "time" }, stamp(v.time)),
        el("td", { "data-label": "Who" }, v.user), el("td", { "data-label": "Note" }, v.note),
        el("td", {}, show, " ", back));
    });
    fill("c-versions", rows, "no version kept yet: the first one applied keeps the file as found too");
  };

  const send = async (path, headline) => {
    try {
      const answer = await api(path, { json: { text: text.value, note: note.value, base } });
      showChecked(answer, headline(answer));
      return answer;
    } catch (e) {
      // A text that doesn't check out comes back 400 with its problems: show them at their keys.
      const detail = e.detail || {};
      showChecked(Object.assign({ ok: false }, detail), e.message);
      return null;
    }
  };

  document.getElementById("c-check").addEventListener("click", () => send("/api/config/check",
    (a) => (a.ok ? "Checks out." : "Does not check out: nothing applied.")));
  document.getElementById("c-apply").addEventListener("click", async () => {
    // What would wait for a restart is said before anything is applied.
    const checked = await send("/api/config/check",
      (a) => (a.ok ? "Checks out." : "Does not check out: nothing applied."));
    if (!checked || !checked.ok) return;
    if (checked.restart_needed.length && !confirm(
      `These keep their running values until a restart: ${checked.restart_needed.join(", ")}. ` +
      "Apply the rest now?")) return;
    const done = await send("/api/config/apply", (a) => `Applied as version ${a.version}. ${a.outcome.join(" ")}`);
    if (done) { note.value = ""; await loadFile(); await loadVersions(); }
  });
  document.getElementById("c-revert").addEventListener("click", () => { text.value = loaded; result.replaceChildren(); });

  (async () => {
    try {
      await loadFile();
      await loadVersions();
      say("on", "ready");
    } catch (e) { say("off", e.message); }
  })();
}

document.addEventListener("DOMContentLoaded", () => {
  if (document.body.dataset.page === "configuration") configurationPage();
});
