// nc-web's page script: live axis table, axis dialog, parameters, scope. Plain JS, no external file.
"use strict";
(function () {
  const cfg = JSON.parse(document.getElementById("cfg").textContent);
  const $ = (id) => document.getElementById(id);
  const state = { axes: [], selected: null, frames: 0, ws: null, jog: null, paused: false, windowS: 10 };
  window.ncweb = state; // for tests and the console

  // ---- live values over the WebSocket -------------------------------------------------------------------------
  function connect() {
    const ws = new WebSocket((location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws/nc/" +
                             encodeURIComponent(cfg.nc));
    state.ws = ws;
    ws.onmessage = (ev) => {
      const m = JSON.parse(ev.data);
      if (m.type === "frame") onFrame(m);
      else if (m.type === "error") showResult(m.error, m.text);
    };
    ws.onclose = () => { state.ws = null; stopJog(); setTimeout(connect, 1000); };
  }

  function fmt(v) { return (Math.abs(v) < 1e-9 ? 0 : v).toFixed(3); }

  function onFrame(m) {
    state.frames += 1;
    const alive = $("alive");
    alive.textContent = m.alive ? "cycle " + m.cycle : "no data";
    alive.className = m.alive ? "live" : "dead";
    state.axes = m.axes;
    if (state.selected === null && m.axes.length) select(m.axes[0].AxisId);
    const body = $("axis-table").tBodies[0];
    for (const a of m.axes) {
      let tr = $("axis-" + a.AxisId);
      if (!tr) {
        tr = body.insertRow();
        tr.id = "axis-" + a.AxisId;
        for (let i = 0; i < 8; i++) tr.insertCell();
        tr.addEventListener("click", () => select(a.AxisId));
        addScopeAxis(a);
      }
      const c = tr.cells;
      c[0].textContent = a.AxisId; c[1].textContent = a.Name;
      c[2].textContent = fmt(a.ActPos); c[3].textContent = fmt(a.SetPos);
      c[4].textContent = fmt(a.ActVelo); c[5].textContent = fmt(a.PosDiff);
      c[6].textContent = a.State + (a.Enabled ? "" : " (disabled)") + (a.Homed ? " homed" : "");
      c[7].textContent = a.ErrorCode ? "0x" + a.ErrorCode.toString(16).toUpperCase() + " " + a.ErrorText : "";
      c[2].className = "actpos"; c[7].className = a.ErrorCode ? "err" : "";
      tr.classList.toggle("selected", a.AxisId === state.selected);
    }
    scopeAdd(m);
  }

  function select(id) {
    state.selected = id;
    if ($("dlg-axis")) $("dlg-axis").textContent = String(id);
    $("param-axis").textContent = "of axis " + id;
  }

  // ---- commands -----------------------------------------------------------------------------------------------
  function showResult(code, text) {
    const r = $("cmd-result");
    if (!r) return;
    r.textContent = code ? "0x" + code.toString(16).toUpperCase() + ": " + text : "accepted";
    r.className = code ? "err" : "ok";
  }

  async function command(cmd, args) {
    if (state.selected === null) return;
    const res = await fetch("/api/nc/" + encodeURIComponent(cfg.nc) + "/axis/" + state.selected + "/" + cmd, {
      method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(args || {}),
      credentials: "same-origin" });
    const j = await res.json().catch(() => ({ error: 0x706, text: "HTTP " + res.status }));
    showResult(j.error, j.text);
    return j;
  }

  const num = (id) => parseFloat($(id).value);

  function startJog(direction) {
    if (state.selected === null || !state.ws) return;
    stopJog();
    const msg = JSON.stringify({ type: "jog", axis: state.selected, direction: direction, velocity: num("jogvelo") || 0 });
    const beat = () => { if (state.ws && state.ws.readyState === 1) state.ws.send(msg); };
    beat();
    state.jog = { axis: state.selected, timer: setInterval(beat, cfg.heartbeat_ms) };
  }

  function stopJog() {
    const j = state.jog;
    if (!j) return;
    clearInterval(j.timer);
    state.jog = null;
    if (state.ws && state.ws.readyState === 1) state.ws.send(JSON.stringify({ type: "jogstop", axis: j.axis }));
  }

  function wireDialog() {
    if (!cfg.op) return;
    $("enable").onclick = () => command("Power", { Enable: true, Override: num("override") });
    $("disable").onclick = () => command("Power", { Enable: false });
    $("reset").onclick = () => command("Reset");
    $("stop").onclick = () => command("Stop");
    $("halt").onclick = () => command("Halt");
    $("moveabs").onclick = () => command("MoveAbsolute", { Position: num("target"), Velocity: num("velo") });
    $("moverel").onclick = () => command("MoveRelative", { Distance: num("target"), Velocity: num("velo") });
    $("home").onclick = () => command("Home", {});
    if (cfg.eng) $("setpos-btn").onclick = () => command("SetActualPosition", { Position: num("setpos") });
    for (const [id, dir] of [["jog-plus", 1], ["jog-minus", 3]]) {
      const b = $(id);
      b.addEventListener("pointerdown", (e) => { e.preventDefault(); startJog(dir); });
      b.addEventListener("mousedown", (e) => { if (!state.jog) startJog(dir); });
      for (const ev of ["pointerup", "pointerleave", "pointercancel", "mouseup", "mouseleave", "blur"])
        b.addEventListener(ev, stopJog);
    }
    window.addEventListener("blur", stopJog);
    document.addEventListener("visibilitychange", () => { if (document.hidden) stopJog(); });
  }

  // ---- parameters ---------------------------------------------------------------------------------------------
  async function readParams(refresh) {
    if (state.selected === null) return;
    const axis = state.selected;
    const res = await fetch("/api/nc/" + encodeURIComponent(cfg.nc) + "/params/" + axis + (refresh ? "?refresh=1" : ""),
                            { credentials: "same-origin" });
    const j = await res.json();
    // a refused or failed read (NC not connected, 0x...) shows why instead of an empty table
    $("param-axis").textContent = "of axis " + axis + (res.ok ? "" : " (read failed: 0x" +
      Number(j.error || 0).toString(16).toUpperCase() + " " + (j.text || res.statusText) + ")");
    const byNo = new Map((j.params || []).map((p) => [p.number, p]));
    const body = $("param-table").tBodies[0];
    body.innerHTML = "";
    for (const p of cfg.params) {
      const v = byNo.get(p.number);
      const tr = body.insertRow();
      tr.id = "param-" + p.name;
      tr.insertCell().textContent = p.number;
      const n = tr.insertCell(); n.textContent = p.name; n.title = p.doc;
      tr.insertCell().textContent = v ? (v.error ? "0x" + v.error.toString(16).toUpperCase() : String(v.value)) : "";
      tr.insertCell().textContent = p.unit;
      if (cfg.eng) {
        const c = tr.insertCell();
        if (p.writable) {
          const inp = document.createElement("input"); inp.size = 10;
          const b = document.createElement("button"); b.textContent = "Write";
          b.onclick = async () => {
            const val = p.bool ? (inp.value === "1" || inp.value.toLowerCase() === "true") : parseFloat(inp.value);
            await command("WriteParameter", { Name: p.name, Value: val });
            readParams(false);
          };
          c.append(inp, b);
        }
      }
    }
  }

  // ---- scope --------------------------------------------------------------------------------------------------
  const SIGS = ["SetPos", "ActPos", "SetVelo", "PosDiff"];
  const COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf"];
  const scope = { t: [], data: new Map(), max: 20000 }; // data: "axis.sig" -> values, aligned with t

  function addScopeAxis(a) {
    const l = document.createElement("label");
    l.innerHTML = '<input type="checkbox" class="scope-axis">';
    l.firstChild.value = a.AxisId;
    l.firstChild.checked = $("scope-axes").children.length === 0;
    l.append(a.Name || "Axis " + a.AxisId);
    $("scope-axes").append(l);
  }

  function scopeAdd(m) {
    if (state.paused || !m.alive) return;
    scope.t.push(m.t);
    for (const a of m.axes)
      for (const s of SIGS) {
        const k = a.AxisId + "." + s;
        if (!scope.data.has(k)) scope.data.set(k, new Array(scope.t.length - 1).fill(NaN));
        scope.data.get(k).push(a[s]);
      }
    if (scope.t.length > scope.max) {
      scope.t.shift();
      for (const v of scope.data.values()) v.shift();
    }
  }

  function chosen() {
    const axes = [...document.querySelectorAll(".scope-axis:checked")].map((e) => e.value);
    const sigs = [...document.querySelectorAll(".sig:checked")].map((e) => e.value);
    const keys = [];
    for (const a of axes) for (const s of sigs) if (scope.data.has(a + "." + s)) keys.push(a + "." + s);
    return keys;
  }

  function draw() {
    const cv = $("scope-canvas"), g = cv.getContext("2d"), W = cv.width, H = cv.height;
    g.fillStyle = "#fff"; g.fillRect(0, 0, W, H);
    $("scope-window").textContent = state.windowS + " s" + (state.paused ? " (paused)" : "");
    const n = scope.t.length;
    if (n < 2) return;
    const tEnd = scope.t[n - 1], tStart = tEnd - state.windowS;
    let i0 = 0;
    while (i0 < n - 1 && scope.t[i0] < tStart) i0++;
    const keys = chosen();
    let lo = Infinity, hi = -Infinity;
    for (const k of keys) for (let i = i0; i < n; i++) {
      const v = scope.data.get(k)[i];
      if (Number.isFinite(v)) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
    }
    if (!Number.isFinite(lo)) return;
    if (hi - lo < 1e-9) { hi += 1; lo -= 1; }
    const pad = 50, x = (t) => pad + (t - tStart) / state.windowS * (W - pad - 10),
          y = (v) => H - 20 - (v - lo) / (hi - lo) * (H - 40);
    g.strokeStyle = "#ccc"; g.fillStyle = "#333"; g.font = "11px sans-serif";
    g.beginPath(); g.moveTo(pad, 10); g.lineTo(pad, H - 20); g.lineTo(W - 10, H - 20); g.stroke();
    g.fillText(hi.toPrecision(5), 2, 20); g.fillText(lo.toPrecision(5), 2, H - 22);
    keys.forEach((k, j) => {
      const v = scope.data.get(k);
      g.strokeStyle = COLORS[j % COLORS.length]; g.beginPath();
      let started = false;
      for (let i = i0; i < n; i++) {
        if (!Number.isFinite(v[i])) { started = false; continue; }
        if (started) g.lineTo(x(scope.t[i]), y(v[i])); else { g.moveTo(x(scope.t[i]), y(v[i])); started = true; }
      }
      g.stroke(); g.fillStyle = g.strokeStyle; g.fillText(k, W - 120, 20 + 13 * j);
    });
  }

  function download(name, href) {
    const a = document.createElement("a");
    a.href = href; a.download = name; document.body.append(a); a.click(); a.remove();
  }

  function exportCsv() {
    const keys = chosen();
    const rows = ["t," + keys.join(",")];
    for (let i = 0; i < scope.t.length; i++) rows.push([scope.t[i].toFixed(3), ...keys.map((k) => scope.data.get(k)[i])].join(","));
    const url = URL.createObjectURL(new Blob([rows.join("\n") + "\n"], { type: "text/csv" }));
    download(cfg.nc + "-scope.csv", url);
    setTimeout(() => URL.revokeObjectURL(url), 1000);
    return rows.length - 1;
  }
  state.exportCsv = exportCsv;

  function wireScope() {
    $("scope-pause").onclick = () => { state.paused = !state.paused; $("scope-pause").textContent = state.paused ? "Run" : "Pause"; };
    $("zoom-in").onclick = () => { state.windowS = Math.max(1, state.windowS / 2); };
    $("zoom-out").onclick = () => { state.windowS = Math.min(600, state.windowS * 2); };
    $("scope-canvas").addEventListener("wheel", (e) => { e.preventDefault(); state.windowS = Math.min(600, Math.max(1, state.windowS * (e.deltaY > 0 ? 1.25 : 0.8))); });
    $("export-csv").onclick = exportCsv;
    $("export-png").onclick = () => download(cfg.nc + "-scope.png", $("scope-canvas").toDataURL("image/png"));
    const loop = () => { draw(); requestAnimationFrame(loop); };
    requestAnimationFrame(loop);
  }

  $("param-read").onclick = () => readParams(false);
  $("param-refresh").onclick = () => readParams(true);
  wireDialog();
  wireScope();
  connect();
})();
