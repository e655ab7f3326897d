// The live view's script: reads the server's event stream (/events) and draws the reports.
// Plain canvas, no plotting library: two plots (beta over time, the per-bin minimum over
// frequency) need lines, dots, a log axis and shading, about two hundred lines here, where a
// library would be a file to vendor, licence and keep; the numbers a reader (or a test)
// checks are in the table's cells and data attributes, not in pixels.
"use strict";
(function () {
  const COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf"];
  const ALARM_COLORS = { OK: "#66bb6a", WARN: "#ffa726", ERROR: "#e53935", STALE: "#9e9e9e" };
  const view = { hello: null, models: new Map(), lastArrival: null, ended: null,
                 connected: false, latencies: [], pending: [], received: 0, dirty: false,
                 binsDirty: false, response: null };
  window.twotankView = view;

  function fmt(x, digits) { return x === null || x === undefined ? "–" : Number(x).toFixed(digits); }
  function attr(x) { return x === null || x === undefined ? "" : String(x); }
  function el(tag, text, cls) {
    const e = document.createElement(tag);
    if (text !== undefined) e.textContent = text;
    if (cls) e.className = cls;
    return e;
  }

  // a base64 string of little-endian float64 values (the server's spectra) as numbers
  function f64(text) {
    const raw = atob(text), bytes = new Uint8Array(raw.length);
    for (let i = 0; i < raw.length; i++) bytes[i] = raw.charCodeAt(i);
    const dv = new DataView(bytes.buffer), out = new Array(bytes.length / 8);
    for (let i = 0; i < out.length; i++) out[i] = dv.getFloat64(i * 8, true);
    return out;
  }

  function model(name) {
    let m = view.models.get(name);
    if (!m) {
      m = { name: name, hist: [], latest: null, spectrum: null, count: 0,
            color: COLORS[view.models.size % COLORS.length], diagnosis: null };
      view.models.set(name, m);
    }
    return m;
  }

  function reset(hello) {
    view.hello = hello;
    view.models = new Map();
    view.ended = null;
    view.lastArrival = null;
    document.getElementById("title").textContent = hello.title ? "— " + hello.title : "";
    document.querySelector("#latest tbody").textContent = "";
    for (const name of Object.keys(hello.models || {})) model(name);
    view.binsDirty = true;
    view.response = null;
    document.getElementById("response").hidden = true;
  }

  function verdict(r) {
    if (r.beta === null) return "not judged: " + (r.reason || "");
    return (r.invalidated ? "INVALIDATED" : "valid") + (r.raised_by ? " (" + r.raised_by + ")" : "");
  }

  function row(m) {
    const body = document.querySelector("#latest tbody");
    let tr = body.querySelector('tr[data-model="' + CSS.escape(m.name) + '"]');
    if (!tr) {
      tr = document.createElement("tr");
      tr.dataset.model = m.name;
      for (const f of ["model", "window", "beta", "beta_op", "beta_total", "verdict", "alarm", "count"]) {
        const td = el("td", "", f === "verdict" ? "verdict" : "");
        td.dataset.field = f;
        tr.appendChild(td);
      }
      body.appendChild(tr);
    }
    const r = m.latest;
    const cell = (f) => tr.querySelector('td[data-field="' + f + '"]');
    tr.dataset.beta = attr(r.beta);
    tr.dataset.betaOp = attr(r.beta_op);
    tr.dataset.betaTotal = attr(r.beta_total);
    tr.dataset.alarm = r.alarm;
    tr.dataset.end = attr(r.end);
    tr.dataset.seq = attr(r.seq);
    tr.dataset.count = String(m.count);
    cell("model").textContent = m.name;
    cell("window").textContent = fmt(r.start, 1) + " – " + fmt(r.end, 1);
    cell("beta").textContent = fmt(r.beta, 3);
    cell("beta_op").textContent = fmt(r.beta_op, 3);
    cell("beta_total").textContent = fmt(r.beta_total, 3);
    cell("verdict").textContent = verdict(r);
    cell("alarm").textContent = r.alarm;
    cell("alarm").className = "alarm-" + r.alarm;
    cell("count").textContent = String(m.count);
  }

  function onReport(r) {
    const m = model(r.model);
    m.count += 1;
    m.hist.push({ start: r.start, end: r.end, beta: r.beta, beta_op: r.beta_op,
                  beta_total: r.beta_total, alarm: r.alarm, reason: r.reason,
                  noise_beta: r.noise_beta });
    const keep = (view.hello && view.hello.history) || 2000;
    if (m.hist.length > keep) m.hist.splice(0, m.hist.length - keep);
    if (!m.latest || r.seq >= m.latest.seq) {
      m.latest = r;
      if (r.diagnosis) m.diagnosis = r;
    }
    row(m);
    view.dirty = true;
  }

  function onMessage(ev) {
    const msg = JSON.parse(ev.data);
    if (msg.type === "hello") { reset(msg); return; }
    if (msg.type === "end") { view.ended = msg.text; status(); return; }
    if (msg.type === "spectrum") {
      // the latest judged window's per-bin minimum of a model (sent after its report)
      const m = model(msg.model);
      if (!m.spectrum || msg.seq >= m.spectrum.seq) {
        m.spectrum = Object.assign({}, msg, { spectrum: {
          freqs_hz: f64(msg.freqs_hz), w_min: f64(msg.w_min),
          noise_floor: msg.noise_floor ? f64(msg.noise_floor) : null,
          excited: msg.excited || null } });
        view.binsDirty = true;
      }
      return;
    }
    if (msg.type === "response") { showResponse(msg); return; }
    if (msg.type === "diagnosis") {
      // an answer of the live diagnosis on its own topic (attached to a running system)
      model(msg.model).diagnosis = { diagnosis: msg.diagnosis };
      view.dirty = true;
      return;
    }
    if (msg.type === "mode") {
      const b = document.getElementById("mode");
      b.hidden = false;
      b.dataset.mode = msg.mode;
      b.dataset.time = attr(msg.time);
      b.dataset.seq = attr(msg.seq);
      b.textContent = "supervisor: " + msg.mode + " (since " + fmt(msg.time, 1) + " s" +
        (msg.reason ? ": " + msg.reason : "") + ")";
      return;
    }
    if (msg.type !== "report") return;
    onReport(msg);
    // when the server pushed it (the same machine's clock: the view is on 127.0.0.1), so
    // that a late visitor's history says how long ago the last report came
    view.lastArrival = Math.min(msg.sent * 1000, Date.now());
    view.received += 1;
    view.pending.push(msg);
    status();
  }

  function learnedHop() {
    let hop = Infinity;
    for (const m of view.models.values()) {
      for (let i = 1; i < m.hist.length; i++) {
        const d = m.hist[i].end - m.hist[i - 1].end;
        if (d > 0 && d < hop) hop = d;
      }
    }
    return Number.isFinite(hop) ? hop : null;
  }

  function staleAfter() {
    const h = view.hello || {};
    if (h.stale_after_s !== null && h.stale_after_s !== undefined) return h.stale_after_s;
    const hop = h.hop_s !== null && h.hop_s !== undefined ? h.hop_s : learnedHop();
    if (hop === null) return 60;
    const speed = h.speed === null || h.speed === undefined ? Infinity : h.speed;
    return Math.max(hop / speed, 0.25);
  }

  function status() {
    const s = document.getElementById("status");
    s.dataset.connected = view.connected ? "1" : "0";
    if (view.lastArrival === null) {
      s.dataset.stopped = "0";
      s.textContent = view.connected ? "connected: waiting for the first report" : "not connected (retrying)";
      return;
    }
    const age = (Date.now() - view.lastArrival) / 1000;
    const stopped = view.ended !== null || age > staleAfter();
    s.dataset.stopped = stopped ? "1" : "0";
    s.dataset.age = age.toFixed(1);
    if (stopped) {
      s.textContent = "reports stopped " + age.toFixed(0) + " s ago" +
        (view.ended ? " (" + view.ended + ")" : "") +
        (view.connected ? "" : "; not connected (retrying)");
    } else {
      s.textContent = "live: last report " + age.toFixed(1) + " s ago";
    }
  }

  // ---- plots ----
  function frame(canvas) {
    const ctx = canvas.getContext("2d");
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    ctx.font = "12px sans-serif";
    return { ctx: ctx, l: 60, r: canvas.width - 15, t: 12, b: canvas.height - 40 };
  }

  function axes(f, xlab, ylab) {
    const c = f.ctx;
    c.strokeStyle = "#888"; c.lineWidth = 1; c.setLineDash([]);
    c.strokeRect(f.l, f.t, f.r - f.l, f.b - f.t);
    c.fillStyle = "#333";
    c.fillText(xlab, (f.l + f.r) / 2 - 30, f.b + 32);
    c.save(); c.translate(14, (f.t + f.b) / 2 + 30); c.rotate(-Math.PI / 2); c.fillText(ylab, 0, 0); c.restore();
  }

  function hline(f, y, dash, color, label) {
    const c = f.ctx;
    c.strokeStyle = color; c.setLineDash(dash); c.lineWidth = 1.2;
    c.beginPath(); c.moveTo(f.l, y); c.lineTo(f.r, y); c.stroke(); c.setLineDash([]);
    if (label) { c.fillStyle = color; c.fillText(label, f.r - 60, y - 3); }
  }

  function ticks(f, lo, hi, toX, toY, log) {
    const c = f.ctx; c.fillStyle = "#333"; c.strokeStyle = "#eee";
    const vals = [];
    if (log) { for (let e = Math.floor(lo); e <= Math.ceil(hi); e++) vals.push(e); }
    else { const step = niceStep((hi - lo) / 6); for (let v = Math.ceil(lo / step) * step; v <= hi; v += step) vals.push(v); }
    return { vals: vals, label: (v) => log ? "1e" + v : String(Math.round(v * 1000) / 1000) };
  }

  function niceStep(raw) {
    const p = Math.pow(10, Math.floor(Math.log10(raw || 1)));
    for (const k of [1, 2, 5, 10]) if (raw <= k * p) return k * p;
    return 10 * p;
  }

  function drawBeta() {
    const canvas = document.getElementById("beta-plot");
    const f = frame(canvas), c = f.ctx;
    const strip = 6, nm = view.models.size;
    const plotB = f.b - strip * nm - 4;
    let t0 = Infinity, t1 = -Infinity, ymax = 1.5;
    for (const m of view.models.values()) for (const h of m.hist) {
      t0 = Math.min(t0, h.start); t1 = Math.max(t1, h.end);
      for (const v of [h.beta, h.beta_total, h.beta_op]) if (v !== null && v !== undefined) ymax = Math.max(ymax, v);
    }
    ymax = Math.min(ymax * 1.05, 10);
    axes(f, "window end (s)", "β");
    if (!(t1 > t0)) return;
    const X = (t) => f.l + (t - t0) / (t1 - t0) * (f.r - f.l);
    const Y = (v) => plotB - Math.min(v, ymax) / ymax * (plotB - f.t);
    const tk = ticks(f, 0, ymax, X, Y, false);
    for (const v of tk.vals) { c.fillStyle = "#333"; c.fillText(tk.label(v), f.l - 35, Y(v) + 4); }
    const xs = ticks(f, t0, t1, X, Y, false);
    for (const v of xs.vals) c.fillText(xs.label(v), X(v) - 12, f.b + 14);
    hline(f, Y(1), [6, 4], "#000", "β = 1");
    let row = 0;
    for (const m of view.models.values()) {
      const series = [["beta", [], 2], ["beta_total", [6, 3], 1.2], ["beta_op", [2, 3], 1.2]];
      for (const [key, dash, width] of series) {
        c.strokeStyle = m.color; c.setLineDash(dash); c.lineWidth = width; c.beginPath();
        let pen = false;
        for (const h of m.hist) {
          const v = h[key];
          if (v === null || v === undefined) { pen = false; continue; }
          if (pen) c.lineTo(X(h.end), Y(v)); else c.moveTo(X(h.end), Y(v));
          pen = true;
        }
        c.stroke();
      }
      c.setLineDash([]);
      // the alarm after each window, a strip per model under the plot
      const y = plotB + 3 + row * strip;
      let prev = null;
      for (const h of m.hist) {
        const a = prev === null ? h.start : prev;
        c.fillStyle = ALARM_COLORS[h.alarm] || "#000";
        c.fillRect(X(a), y, Math.max(X(h.end) - X(a), 1), strip - 1);
        prev = h.end;
      }
      row++;
    }
    const lg = document.getElementById("beta-legend");
    lg.textContent = "";
    for (const m of view.models.values()) {
      const s = el("span"); const sw = el("span", "", "swatch"); sw.style.background = m.color;
      s.appendChild(sw); s.appendChild(document.createTextNode("model " + m.name)); lg.appendChild(s);
    }
    lg.appendChild(el("span", "solid β (dynamics), dashed β_total, dotted β_op; strips under the plot: alarm per model (green OK, amber WARN, red ERROR, grey STALE)"));
  }

  function drawBins() {
    const canvas = document.getElementById("bin-plot");
    const f = frame(canvas), c = f.ctx;
    axes(f, "frequency (Hz)", "min ‖W(n)‖");
    let flo = Infinity, fhi = -Infinity, whi = 1;
    const pos = [];
    for (const m of view.models.values()) {
      if (!m.spectrum) continue;
      const s = m.spectrum.spectrum;
      for (let i = 0; i < s.freqs_hz.length; i++) {
        flo = Math.min(flo, s.freqs_hz[i]); fhi = Math.max(fhi, s.freqs_hz[i]);
        const w = s.w_min[i];
        if (Number.isFinite(w) && w > 0) { pos.push(w); whi = Math.max(whi, w); }
      }
    }
    if (!(fhi > flo)) return;
    // the axis starts under most bins (a bin far below the rest, e.g. one the model fits
    // exactly, sits on the axis): the 5th percentile over 3, at most 1e-2
    pos.sort((a, b) => a - b);
    let wlo = pos.length ? pos[Math.floor(pos.length * 0.05)] / 3 : 1e-3;
    wlo = Math.max(Math.min(wlo, 1e-2), 1e-12);
    const lx0 = Math.log10(flo), lx1 = Math.log10(fhi), ly0 = Math.log10(wlo), ly1 = Math.log10(whi * 1.5);
    const X = (x) => f.l + (Math.log10(x) - lx0) / (lx1 - lx0) * (f.r - f.l);
    const Y = (y) => f.b - (Math.log10(Math.max(y, wlo)) - ly0) / (ly1 - ly0) * (f.b - f.t);
    const yt = ticks(f, ly0, ly1, X, Y, true);
    for (const e of yt.vals) if (e >= ly0 && e <= ly1) { c.fillStyle = "#333"; c.fillText(yt.label(e), f.l - 40, Y(Math.pow(10, e)) + 4); }
    const xt = ticks(f, lx0, lx1, X, Y, true);
    for (const e of xt.vals) if (e >= lx0 && e <= lx1) c.fillText(xt.label(e), X(Math.pow(10, e)) - 12, f.b + 14);
    const notes = [];
    // the excited band (the lines the command excites, as the report's excited bins say),
    // shaded once: the models judge the same window of the same command
    let exc = null;
    for (const m of view.models.values()) {
      const s = m.spectrum && m.spectrum.spectrum;
      if (s && s.excited && s.excited.length) { exc = s; break; }
    }
    if (exc) {
      const fe = exc.excited.map((i) => exc.freqs_hz[i]);
      const lo = Math.min.apply(null, fe), hi = Math.max.apply(null, fe);
      c.fillStyle = "#2ca02c16";
      c.fillRect(X(lo) - 2, f.t, Math.max(X(hi) - X(lo), 1) + 4, f.b - f.t);
      notes.push("shaded green: the excited band " + lo.toPrecision(3) + " – " + hi.toPrecision(3) + " Hz (" + fe.length + " excited lines: markers joined; the other bins faint)");
    }
    for (const m of view.models.values()) {
      if (!m.spectrum) continue;
      const band = (view.hello && view.hello.models && view.hello.models[m.name]) || null;
      if (band) {
        // the model's own band (the bins its β counts): dashed edges in its colour
        c.strokeStyle = m.color; c.lineWidth = 1; c.setLineDash([4, 3]);
        for (const hz of [band.min_hz, band.max_hz]) {
          if (hz === null || !(hz > flo && hz < fhi)) continue;
          c.beginPath(); c.moveTo(X(hz), f.t); c.lineTo(X(hz), f.b); c.stroke();
        }
        c.setLineDash([]);
        notes.push("dashed edges: model " + m.name + "'s band " + band.min_hz + " – " + (band.max_hz === null ? "Nyquist" : band.max_hz) + " Hz" + (band.excited ? " (its excited lines only)" : "") + ", the bins its β counts");
      }
      const s = m.spectrum.spectrum;
      const excited = new Set(s.excited || []);
      const all = !s.excited;  // no excited bins in the report: every bin drawn alike
      // the bins not excited (only noise there): faint dots
      c.fillStyle = m.color + "55";
      for (let i = 0; i < s.freqs_hz.length; i++) {
        const w = s.w_min[i];
        if (!Number.isFinite(w) || (!all && excited.has(i))) continue;
        c.fillRect(X(s.freqs_hz[i]) - 1, Y(w) - 1, 2, 2);
      }
      // the excited lines: markers joined in order
      if (!all) {
        c.strokeStyle = m.color; c.fillStyle = m.color; c.lineWidth = 1; c.beginPath();
        let pen = false;
        for (const i of s.excited) {
          const w = s.w_min[i];
          if (!Number.isFinite(w)) { pen = false; continue; }
          if (pen) c.lineTo(X(s.freqs_hz[i]), Y(w)); else c.moveTo(X(s.freqs_hz[i]), Y(w));
          pen = true;
        }
        c.stroke();
        for (const i of s.excited) if (Number.isFinite(s.w_min[i])) c.fillRect(X(s.freqs_hz[i]) - 2, Y(s.w_min[i]) - 2, 4, 4);
      }
      // the per-bin noise floor: what the window's noise alone is expected to cost per bin
      const nf = s.noise_floor;
      if (nf && nf.some((v) => Number.isFinite(v) && v > 0)) {
        c.strokeStyle = m.color; c.lineWidth = 1.2; c.setLineDash([2, 3]); c.beginPath();
        let pen = false;
        for (let i = 0; i < nf.length; i++) {
          if (!(Number.isFinite(nf[i]) && nf[i] > 0)) { pen = false; continue; }
          if (pen) c.lineTo(X(s.freqs_hz[i]), Y(nf[i])); else c.moveTo(X(s.freqs_hz[i]), Y(nf[i]));
          pen = true;
        }
        c.stroke(); c.setLineDash([]);
        const nb = m.spectrum.noise_beta;
        notes.push("dotted: model " + m.name + "'s noise floor per bin (what the window's noise alone is expected to cost" + (nb === null || nb === undefined ? "" : "; over the band noise_beta " + nb.toPrecision(3)) + ")");
      } else {
        notes.push("model " + m.name + ": no noise floor (one period per window, no noise channels, or a report without it)");
      }
    }
    hline(f, Y(1), [6, 4], "#000", "1");
    const lg = document.getElementById("bin-legend");
    lg.textContent = "";
    for (const m of view.models.values()) {
      if (!m.spectrum) continue;
      const s = el("span"); const sw = el("span", "", "swatch"); sw.style.background = m.color;
      s.appendChild(sw);
      s.appendChild(document.createTextNode("model " + m.name + ", window " + fmt(m.spectrum.start, 1) + " – " + fmt(m.spectrum.end, 1) + " s, β " + fmt(m.spectrum.beta, 3)));
      lg.appendChild(s);
    }
    for (const n of notes) lg.appendChild(el("span", n));
    if (!notes.some((n) => n.startsWith("dashed"))) lg.appendChild(el("span", "no band: every bin counts"));
  }

  // ---- the identified response (--view-response: identify --json's report, sent once) ----
  function mag(p) { return p === null ? null : Math.hypot(p[0], p[1]); }

  function showResponse(msg) {
    view.response = msg;
    document.getElementById("response").hidden = false;
    document.getElementById("response-source").textContent = "— " + msg.source +
      (msg.matched === "shape" ? " (it names no channels: entries taken by shape as the models' " +
        msg.outputs.join(", ") + " × " + msg.inputs.join(", ") + ")" : "");
    const body = document.querySelector("#response-table tbody");
    body.textContent = "";
    for (const e of msg.entries) {
      for (let k = 0; k < msg.freqs_hz.length; k++) {
        const tr = document.createElement("tr");
        const d = tr.dataset;
        d.output = e.output; d.input = e.input; d.freq = attr(msg.freqs_hz[k]);
        const m = e.measured[k], n = e.nominal[k];
        d.measuredRe = attr(m && m[0]); d.measuredIm = attr(m && m[1]);
        d.stdNoise = attr(e.std_noise[k]); d.stdTotal = attr(e.std_total[k]);
        d.stdDistortion = attr(e.std_distortion ? e.std_distortion[k] : null);
        d.nominalRe = attr(n && n[0]); d.nominalIm = attr(n && n[1]);
        d.weight = attr(e.weight[k]);
        const p = (x) => x === null || x === undefined ? "–" : Number(x).toPrecision(4);
        for (const text of [e.output, e.input, p(msg.freqs_hz[k]), p(mag(m)), p(e.std_noise[k]),
                            e.std_distortion ? p(e.std_distortion[k]) : "–", p(e.std_total[k]),
                            p(mag(n)), p(e.weight[k])]) tr.appendChild(el("td", text));
        body.appendChild(tr);
      }
    }
    drawResponse();
  }

  function drawResponse() {
    const msg = view.response, box = document.getElementById("response-plots");
    box.textContent = "";
    const fs = msg.freqs_hz.filter((x) => x !== null && x > 0);
    if (!fs.length) return;
    const flo = Math.min.apply(null, fs), fhi = Math.max.apply(null, fs);
    // the axis reaches a little past the excited lines, so that their band shows as a band
    const lx0 = Math.log10(flo) - 0.25, lx1 = Math.log10(fhi) + 0.25;
    const split = msg.entries.some((e) => e.std_distortion && e.std_distortion.some((v) => v > 0));
    for (const e of msg.entries) {
      const canvas = document.createElement("canvas");
      canvas.width = 590; canvas.height = 280;
      canvas.dataset.output = e.output; canvas.dataset.input = e.input;
      canvas.setAttribute("aria-label", "identified response " + e.output + " / " + e.input);
      box.appendChild(canvas);
      const f = frame(canvas), c = f.ctx;
      axes(f, "frequency (Hz)", "|G|");
      c.fillStyle = "#333"; c.fillText(e.output + " / " + e.input, f.l + 6, f.t + 14);
      const pts = [];  // [f, |Ĥ|, σ noise, σ total, |G nominal|, |W|]
      for (let k = 0; k < msg.freqs_hz.length; k++) {
        const hz = msg.freqs_hz[k];
        if (!(hz > 0)) continue;
        pts.push([hz, mag(e.measured[k]), e.std_noise[k], e.std_total[k], mag(e.nominal[k]), e.weight[k]]);
      }
      const vals = [];
      for (const [, g, , st, gn, w] of pts) {
        for (const v of [g, g === null || st === null ? null : g + st, gn,
                         gn === null || w === null ? null : gn * (1 + w),
                         gn === null || w === null ? null : gn * (1 - w)]) if (v !== null && v > 0) vals.push(v);
      }
      if (!vals.length) continue;
      const ly0 = Math.log10(Math.min.apply(null, vals)) - 0.15, ly1 = Math.log10(Math.max.apply(null, vals)) + 0.15;
      const X = (x) => f.l + (Math.log10(x) - lx0) / (lx1 - lx0) * (f.r - f.l);
      const Y = (y) => f.b - (Math.log10(Math.max(y, Math.pow(10, ly0))) - ly0) / (ly1 - ly0) * (f.b - f.t);
      const yt = ticks(f, ly0, ly1, X, Y, true);
      for (const v of yt.vals) if (v >= ly0 && v <= ly1) { c.fillStyle = "#333"; c.fillText(yt.label(v), f.l - 40, Y(Math.pow(10, v)) + 4); }
      const xt = ticks(f, lx0, lx1, X, Y, true);
      for (const v of xt.vals) if (v >= lx0 && v <= lx1) c.fillText(xt.label(v), X(Math.pow(10, v)) - 12, f.b + 14);
      // the excited band: the lines the report has (each an excited line in the band)
      c.fillStyle = "#2ca02c16";
      c.fillRect(X(flo) - 2, f.t, X(fhi) - X(flo) + 4, f.b - f.t);
      // the nominal with its weight: |G|(1 ± |W|), the magnitudes the model set allows
      c.fillStyle = "#ff7f0e33"; c.beginPath();
      const band = pts.filter((p) => p[4] !== null && p[5] !== null);
      band.forEach((p, i) => { const y = Y(p[4] * (1 + p[5])); if (i) c.lineTo(X(p[0]), y); else c.moveTo(X(p[0]), y); });
      for (let i = band.length - 1; i >= 0; i--) c.lineTo(X(band[i][0]), Y(Math.max(band[i][4] * (1 - band[i][5]), 0)));
      c.closePath(); c.fill();
      c.strokeStyle = "#ff7f0e"; c.lineWidth = 1.6; c.beginPath();
      band.forEach((p, i) => { if (i) c.lineTo(X(p[0]), Y(p[4])); else c.moveTo(X(p[0]), Y(p[4])); });
      c.stroke();
      // the measured response: points with ±σ (total thin; noise thick where they differ)
      for (const [hz, g, sn, st] of pts) {
        if (g === null) continue;
        const x = X(hz);
        c.strokeStyle = "#1f77b4";
        if (st !== null) { c.lineWidth = 1; c.beginPath(); c.moveTo(x, Y(g + st)); c.lineTo(x, Y(Math.max(g - st, 0))); c.stroke(); }
        if (split && sn !== null) { c.lineWidth = 3; c.beginPath(); c.moveTo(x, Y(g + sn)); c.lineTo(x, Y(Math.max(g - sn, 0))); c.stroke(); }
        c.fillStyle = "#1f77b4"; c.fillRect(x - 2, Y(g) - 2, 4, 4);
      }
    }
    const lg = document.getElementById("response-legend");
    lg.textContent = "";
    lg.appendChild(el("span", "blue points: the measured response |Ĥ| at each excited line, bars ± σ " +
      (split ? "(thick: the noise's; thin: the total, noise and nonlinear distortion)" : "(the noise's; the record shows no nonlinear distortion)")));
    lg.appendChild(el("span", "orange line: the nominal |G|; shaded orange: |G|(1 ± |W|), the magnitudes the model set allows (output-multiplicative weight)"));
    lg.appendChild(el("span", "shaded green: the excited band " + flo.toPrecision(3) + " – " + fhi.toPrecision(3) + " Hz (" + fs.length + " lines)"));
  }

  function drawLists() {
    const diag = document.getElementById("diagnosis");
    diag.textContent = "";
    for (const m of view.models.values()) {
      if (!m.diagnosis) continue;
      const d = m.diagnosis.diagnosis;
      const box = el("div", "", "diag"); box.dataset.model = m.name; box.dataset.kind = d.kind;
      const params = Object.entries(d.parameters).map(([k, v]) => k + " " + Number(v).toPrecision(3)).join(", ");
      box.appendChild(el("strong", "model " + m.name + ": " + d.kind + (d.channel ? " on " + d.channel : "") + (params ? " (" + params + ")" : "")));
      box.appendChild(el("div", "probability " + (d.probability === null ? "not measured" : d.probability.toFixed(3)) +
        ", score " + Number(d.score).toPrecision(3) + "; answer " + d.update + ", from " + d.windows + " window(s) after " + fmt(d.onset, 1) + " s"));
      box.appendChild(el("div", "evidence: " + d.summary));
      diag.appendChild(box);
    }
    if (!diag.children.length) diag.appendChild(el("p", "no diagnosis (none is made before an alarm rises)", "muted"));
    const spells = document.getElementById("spells");
    spells.textContent = "";
    const items = [];
    for (const m of view.models.values()) {
      let run = null;
      for (const h of m.hist) {
        if (h.alarm === "STALE" || h.reason) {
          if (run && run.reason === (h.reason || "") && run.stale === (h.alarm === "STALE")) { run.end = h.end; run.n++; }
          else { run = { model: m.name, start: h.start, end: h.end, n: 1, reason: h.reason || "", stale: h.alarm === "STALE" }; items.push(run); }
        } else run = null;
      }
    }
    items.sort((a, b) => b.end - a.end);
    for (const it of items.slice(0, 30)) {
      const li = el("li", "model " + it.model + ", " + fmt(it.start, 1) + " – " + fmt(it.end, 1) + " s (" + it.n + " window(s))" +
        (it.stale ? ": STALE" : "") + (it.reason ? ": " + it.reason : ""));
      li.dataset.model = it.model; li.dataset.stale = it.stale ? "1" : "0";
      spells.appendChild(li);
    }
    if (!items.length) spells.appendChild(el("li", "none", "muted"));
    const warn = document.getElementById("warnings");
    warn.textContent = "";
    for (const m of view.models.values()) for (const w of (m.latest && m.latest.warnings) || []) warn.appendChild(el("li", "model " + m.name + ": " + w));
    if (!warn.children.length) warn.appendChild(el("li", "none", "muted"));
  }

  function redraw() {
    // the per-bin plot changes only with a spectrum (at most every 0.1 s a model), the rest
    // with every report: a replay as fast as it goes redraws it that much less often
    if (view.binsDirty) {
      view.binsDirty = false;
      drawBins();
    }
    if (view.dirty) {
      view.dirty = false;
      drawBeta(); drawLists();
      document.body.dataset.drawn = String(view.received);
      // latency: from the report pushed (the server's clock) to the frame that draws it
      const now = Date.now();
      for (const m of view.pending) view.latencies.push({ seq: m.seq, ms: now - m.sent * 1000 });
      view.pending = [];
      if (view.latencies.length > 5000) view.latencies.splice(0, 1000);
    }
    requestAnimationFrame(redraw);
  }

  const source = new EventSource("events");
  source.onopen = function () { view.connected = true; status(); };
  source.onerror = function () { view.connected = false; status(); };
  source.onmessage = onMessage;
  setInterval(status, 250);
  requestAnimationFrame(redraw);
})();
