// Runs nc-scope's page script in node with a minimal DOM: every canvas call is recorded.
// usage: node scope_page_harness.js PAGE.html  -> prints a JSON report on stdout
"use strict";
const fs = require("fs");
const vm = require("vm");
const page = fs.readFileSync(process.argv[2], "utf8");
const data = /<script type="application\/json" id="scope-data">([\s\S]*?)<\/script>/.exec(page)[1];
const scripts = [...page.matchAll(/<script>([\s\S]*?)<\/script>/g)].map((m) => m[1]);
const calls = {};
const strokes = [];  // strokeStyle at every stroke()
function ctx() {
  const state = {};
  return new Proxy({}, {
    get(_, k) {
      if (k in state) return state[k];
      return (...args) => {
        calls[k] = (calls[k] || 0) + 1;
        if (k === "stroke") strokes.push(state.strokeStyle);
        for (const a of args) if (typeof a === "number" && !Number.isFinite(a)) throw new Error(`${String(k)}(${args}) not finite`);
      };
    },
    set(_, k, v) { state[k] = v; return true; },
  });
}
const elements = {};
function element(tag, id) {
  const listeners = {};
  const el = {
    tag, id, style: {}, children: [], textContent: "", className: "", clientWidth: 900, clientHeight: 220,
    appendChild(c) { this.children.push(c); return c; },
    addEventListener(type, fn) { (listeners[type] = listeners[type] || []).push(fn); },
    fire(type, ev) { for (const fn of listeners[type] || []) fn(Object.assign({preventDefault() {}}, ev)); },
    getBoundingClientRect() { return {left: 0, top: 0, width: 900, height: 220}; },
    getContext() { return this._ctx || (this._ctx = ctx()); },
  };
  return el;
}
const canvases = [];
const document = {
  getElementById(id) {
    if (!elements[id]) { elements[id] = element("div", id); if (id === "scope-data") elements[id].textContent = data; }
    return elements[id];
  },
  createElement(tag) { const e = element(tag); if (tag === "canvas") canvases.push(e); return e; },
  createTextNode(t) { return {text: t}; },
};
const win = {devicePixelRatio: 1, _l: {}, addEventListener(t, fn) { (this._l[t] = this._l[t] || []).push(fn); }};
const sandbox = {document, window: win, JSON, Math, String, Number, Infinity, console};
vm.createContext(sandbox);
for (const s of scripts) vm.runInContext(s, sandbox);
const api = win.ncScope;
const report = {charts: canvases.length, initialLineTo: calls.lineTo || 0, strokesInitial: strokes.slice()};
const v0 = api.view();
canvases[0].fire("wheel", {clientX: 450, deltaY: -100});   // zoom in
const v1 = api.view();
canvases[0].fire("mousemove", {clientX: 300});
const tip = document.getElementById("tip").textContent;
canvases[0].fire("mousedown", {clientX: 300});
canvases[0].fire("mousemove", {clientX: 200});                // pan
for (const fn of win._l.mouseup || []) fn({});
const v2 = api.view();
canvases[0].fire("dblclick", {});
const v3 = api.view();
const mid = (v0[0] + v0[1]) / 2;
report.views = [v0, v1, v2, v3];
report.tip = tip;
report.hover = api.hoverAt(mid);
report.lineTo = calls.lineTo || 0;
report.legendItems = document.getElementById("legend").children.length;
process.stdout.write(JSON.stringify(report));
