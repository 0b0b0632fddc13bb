/* uwval interactive charts: hand-written SVG, no library, no network.
   Wheel zooms (time charts: time axis, shift+wheel: value axis; trajectory: both axes,
   equal scale), drag pans, double-click or "reset" restores the full view. Each chart's
   SVG carries its visible range in data-view="x0,x1,y0,y1" (data units). */
(function () {
  "use strict";
  var NS = "http://www.w3.org/2000/svg";

  function el(tag, attrs, parent) {
    var e = document.createElementNS(NS, tag);
    for (var k in attrs) { if (attrs[k] !== undefined) e.setAttribute(k, attrs[k]); }
    if (parent) parent.appendChild(e);
    return e;
  }

  var N_COLOURS = 32;

  function jet(t) {  /* matplotlib's "jet" colour map, t in [0, 1] */
    function c(v) { return Math.round(255 * Math.max(0, Math.min(1, v))); }
    return "rgb(" + c(1.5 - Math.abs(4 * t - 3)) + "," + c(1.5 - Math.abs(4 * t - 2)) + "," +
      c(1.5 - Math.abs(4 * t - 1)) + ")";
  }

  function niceStep(span, n) {
    var raw = span / n, mag = Math.pow(10, Math.floor(Math.log10(raw))), f = raw / mag;
    return (f < 1.5 ? 1 : f < 3 ? 2 : f < 7 ? 5 : 10) * mag;
  }

  function ticks(lo, hi, n) {
    var span = hi - lo;
    if (!(span > 0) || !isFinite(span)) return { step: 1, values: [lo] };
    var step = niceStep(span, n), out = [];
    for (var i = Math.ceil(lo / step); i * step <= hi + step * 1e-9 && out.length < 50; i++) {
      out.push(i * step);
    }
    return { step: step, values: out };
  }

  function label(v, step) {
    if (v === 0 || Math.abs(v) < step * 1e-9) return "0";
    var a = Math.abs(v);
    if (a >= 1e6 || a < 1e-4) return v.toExponential(Math.max(0, Math.min(10, Math.round(Math.log10(a / step)))));
    var d = Math.max(0, Math.min(12, -Math.floor(Math.log10(step) + 1e-9)));
    return v.toFixed(d);
  }

  function extent(series, key, from, to) {
    var lo = Infinity, hi = -Infinity;
    series.forEach(function (s) {
      var xs = s.x, vs = s[key];
      for (var i = 0; i < vs.length; i++) {
        var v = vs[i];
        if (v === null || !isFinite(v)) continue;
        if (from !== undefined && (xs[i] < from || xs[i] > to)) continue;
        if (v < lo) lo = v;
        if (v > hi) hi = v;
      }
    });
    if (lo > hi) { lo = 0; hi = 1; }
    if (lo === hi) { var p = Math.abs(lo) * 1e-6 || 1e-9; lo -= p; hi += p; }
    var pad = (hi - lo) * 0.04;
    return [lo - pad, hi + pad];
  }

  function Chart(host, opts) {
    this.opts = opts;
    this.W = 900; this.H = opts.height || 280;
    this.m = { l: 78, r: 16, t: 12, b: 42 };
    this.pw = this.W - this.m.l - this.m.r;
    this.ph = this.H - this.m.t - this.m.b;
    var svg = el("svg", { viewBox: "0 0 " + this.W + " " + this.H, "class": "chart",
      id: opts.id, role: "img", "aria-label": opts.title }, host);
    this.svg = svg;
    var defs = el("defs", {}, svg);
    var cp = el("clipPath", { id: opts.id + "-clip" }, defs);
    el("rect", { x: this.m.l, y: this.m.t, width: this.pw, height: this.ph }, cp);
    this.gAxes = el("g", { "class": "axes" }, svg);
    this.gData = el("g", { "clip-path": "url(#" + opts.id + "-clip)" }, svg);
    this.paths = opts.series.map(function (s) {
      if (s.c) {  // coloured by a value: one path per colour bin
        // a segment's colour is the mean value of its two ends: the colour scale spans those
        var lo = Infinity, hi = -Infinity;
        for (var i = 0; i + 1 < s.c.length; i++) {
          if (s.c[i] === null || s.c[i + 1] === null) continue;
          var m = (s.c[i] + s.c[i + 1]) / 2;
          if (m < lo) lo = m;
          if (m > hi) hi = m;
        }
        s.cRange = lo <= hi ? [lo, hi] : [0, 1];
        var bins = [];
        for (var k = 0; k < N_COLOURS; k++) {
          bins.push(el("path", { fill: "none", stroke: jet((k + 0.5) / N_COLOURS),
            "stroke-width": s.width || 2.2, "stroke-linecap": "round", "class": "cbin" }, this.gData));
        }
        return bins;
      }
      return el("path", { fill: "none", stroke: s.color, "stroke-width": s.width || 1.3,
        "stroke-dasharray": s.dash, "stroke-linejoin": "round" }, this.gData);
    }, this);
    var x = extent(opts.series, "x"), y = extent(opts.series, "y");
    this.home = this.equalise([x[0], x[1], y[0], y[1]]);
    this.view = this.home.slice();
    this.linked = [];
    this.yManual = false;
    this.listen();
    this.draw();
  }

  Chart.prototype.equalise = function (v) {
    if (!this.opts.equal) return v;
    var ux = (v[1] - v[0]) / this.pw, uy = (v[3] - v[2]) / this.ph, u = Math.max(ux, uy);
    var cx = (v[0] + v[1]) / 2, cy = (v[2] + v[3]) / 2;
    return [cx - u * this.pw / 2, cx + u * this.pw / 2, cy - u * this.ph / 2, cy + u * this.ph / 2];
  };

  Chart.prototype.px = function (x) { var v = this.view; return this.m.l + (x - v[0]) / (v[1] - v[0]) * this.pw; };
  Chart.prototype.py = function (y) { var v = this.view; return this.m.t + (v[3] - y) / (v[3] - v[2]) * this.ph; };

  Chart.prototype.toData = function (evt) {
    var r = this.svg.getBoundingClientRect();
    var sx = (evt.clientX - r.left) * this.W / r.width, sy = (evt.clientY - r.top) * this.H / r.height;
    var v = this.view;
    return { x: v[0] + (sx - this.m.l) / this.pw * (v[1] - v[0]),
             y: v[3] - (sy - this.m.t) / this.ph * (v[3] - v[2]),
             sx: sx, sy: sy, kx: this.W / r.width, ky: this.H / r.height };
  };

  Chart.prototype.setView = function (v, fromLink) {
    this.view = v;
    if (!this.opts.equal && !this.yManual) {
      var y = extent(this.opts.series, "y", v[0], v[1]);
      this.view = [v[0], v[1], y[0], y[1]];
    }
    this.draw();
    if (!fromLink) {
      var self = this;
      this.linked.forEach(function (c) { c.setView([self.view[0], self.view[1], c.view[2], c.view[3]], true); });
    }
  };

  /* Time charts: the values of every series at the sample nearest the pointer, in the
     chart's top-left corner, with a vertical cursor line (hidden when the pointer leaves). */
  Chart.prototype.readout = function (evt) {
    if (this.opts.equal) return;
    if (!this.cursor) {
      this.cursor = el("line", { stroke: "#57606a", "stroke-width": 0.8, "stroke-dasharray": "2 2" }, this.svg);
      this.readoutText = el("text", { x: this.m.l + 6, y: this.m.t + 14, "class": "readout" }, this.svg);
    }
    var xs = this.opts.series.length ? this.opts.series[0].x : [];
    var p = evt ? this.toData(evt) : null;
    if (!p || !xs.length || p.sx < this.m.l || p.sx > this.m.l + this.pw) {
      this.cursor.setAttribute("visibility", "hidden");
      this.readoutText.textContent = "";
      return;
    }
    var hi = Math.min(xs.length - 1, bisect(xs, p.x)), lo = Math.max(0, hi - 1);
    var i = Math.abs(xs[lo] - p.x) <= Math.abs(xs[hi] - p.x) ? lo : hi;
    var x = this.px(xs[i]);
    this.cursor.setAttribute("x1", x); this.cursor.setAttribute("x2", x);
    this.cursor.setAttribute("y1", this.m.t); this.cursor.setAttribute("y2", this.m.t + this.ph);
    this.cursor.setAttribute("visibility", "visible");
    var parts = this.opts.series.map(function (s) {
      var v = s.y[i];
      return s.label + " " + (v === null ? "n/a" : Number(v).toPrecision(4));
    });
    this.readoutText.textContent = "t = " + Number(xs[i]).toFixed(3) + " s: " + parts.join(", ") + " " + (this.opts.unit || "");
  };

  Chart.prototype.zoomBy = function (f) {  // about the centre (buttons, keyboard, touch)
    var v = this.view, cx = (v[0] + v[1]) / 2, cy = (v[2] + v[3]) / 2, nv = v.slice();
    nv[0] = cx + (v[0] - cx) * f; nv[1] = cx + (v[1] - cx) * f;
    if (this.opts.equal) { nv[2] = cy + (v[2] - cy) * f; nv[3] = cy + (v[3] - cy) * f; }
    this.setView(nv);
  };

  Chart.prototype.reset = function () {
    this.yManual = false;
    this.setView(this.home.slice());
  };

  Chart.prototype.listen = function () {
    var self = this, drag = null;
    this.svg.addEventListener("wheel", function (evt) {
      evt.preventDefault();
      var p = self.toData(evt), f = Math.exp(Math.max(-1, Math.min(1, evt.deltaY * 0.002))), v = self.view;
      var zx = self.opts.equal || !evt.shiftKey, zy = self.opts.equal || evt.shiftKey;
      var nv = v.slice();
      if (zx) { nv[0] = p.x + (v[0] - p.x) * f; nv[1] = p.x + (v[1] - p.x) * f; }
      if (zy) { nv[2] = p.y + (v[2] - p.y) * f; nv[3] = p.y + (v[3] - p.y) * f; self.yManual = !self.opts.equal; }
      self.setView(nv);
    }, { passive: false });
    this.svg.addEventListener("pointerdown", function (evt) {
      if (evt.button !== 0) return;
      drag = { p: self.toData(evt), view: self.view.slice() };
      if (self.svg.setPointerCapture) { try { self.svg.setPointerCapture(evt.pointerId); } catch (e) { /* synthetic */ } }
      self.svg.classList.add("dragging");
    });
    this.svg.addEventListener("pointermove", function (evt) {
      if (!drag) { self.readout(evt); return; }
      var p = self.toData(evt), v = drag.view;
      var dx = (p.sx - drag.p.sx) / self.pw * (v[1] - v[0]);
      var dy = (p.sy - drag.p.sy) / self.ph * (v[3] - v[2]);
      if (!self.opts.equal && dy !== 0) self.yManual = true;
      self.setView([v[0] - dx, v[1] - dx, v[2] + dy, v[3] + dy]);
    });
    function end() { drag = null; self.svg.classList.remove("dragging"); }
    this.svg.addEventListener("pointerleave", function () { self.readout(null); });
    this.svg.addEventListener("pointerup", end);
    this.svg.addEventListener("pointercancel", end);
    this.svg.addEventListener("dblclick", function () { self.reset(); });
  };

  Chart.prototype.draw = function () {
    var v = this.view, g = this.gAxes, m = this.m, self = this;
    while (g.firstChild) g.removeChild(g.firstChild);
    el("rect", { x: m.l, y: m.t, width: this.pw, height: this.ph, fill: "#fff", stroke: "#8c959f" }, g);
    var tx = ticks(v[0], v[1], 8), ty = ticks(v[2], v[3], 5);
    tx.values.forEach(function (t) {
      var x = self.px(t);
      el("line", { x1: x, x2: x, y1: m.t, y2: m.t + self.ph, stroke: "#d0d7de", "stroke-width": 0.6 }, g);
      el("text", { x: x, y: m.t + self.ph + 15, "text-anchor": "middle", "class": "tick" }, g).textContent = label(t, tx.step);
    });
    ty.values.forEach(function (t) {
      var y = self.py(t);
      el("line", { x1: m.l, x2: m.l + self.pw, y1: y, y2: y, stroke: "#d0d7de", "stroke-width": 0.6 }, g);
      el("text", { x: m.l - 6, y: y + 4, "text-anchor": "end", "class": "tick" }, g).textContent = label(t, ty.step);
    });
    el("text", { x: m.l + this.pw / 2, y: this.H - 6, "text-anchor": "middle", "class": "axis-label" }, g).textContent = this.opts.xlabel;
    el("text", { x: 14, y: m.t + this.ph / 2, "text-anchor": "middle", "class": "axis-label",
      transform: "rotate(-90 14 " + (m.t + this.ph / 2) + ")" }, g).textContent = this.opts.ylabel;
    this.opts.series.forEach(function (s, k) {
      if (s.c) { self.drawColoured(s, self.paths[k]); return; }
      if (!self.opts.equal) { self.paths[k].setAttribute("d", self.timePath(s)); return; }
      var d = [], pen = false;
      for (var i = 0; i < s.x.length; i++) {
        var a = s.x[i], b = s.y[i];
        if (a === null || b === null || !isFinite(a) || !isFinite(b)) { pen = false; continue; }
        d.push((pen ? "L" : "M") + self.px(a).toFixed(2) + " " + self.py(b).toFixed(2));
        pen = true;
      }
      self.paths[k].setAttribute("d", d.join(""));
    });
    this.svg.setAttribute("data-view", v.map(function (x) { return x.toPrecision(10); }).join(","));
  };

  function bisect(xs, x) {  // first index whose stamp is >= x (stamps increase; nulls none)
    var lo = 0, hi = xs.length;
    while (lo < hi) { var mid = (lo + hi) >> 1; if (xs[mid] < x) lo = mid + 1; else hi = mid; }
    return lo;
  }

  /* A time series' path: only the samples in view (plus one either side), and where there
     are more than two per pixel, per pixel column the minimum and the maximum (in their
     order): the drawn envelope is the same as with every sample, at a few thousand points. */
  Chart.prototype.timePath = function (s) {
    var xs = s.x, ys = s.y, v = this.view;
    var i0 = Math.max(0, bisect(xs, v[0]) - 1), i1 = Math.min(xs.length, bisect(xs, v[1]) + 1);
    var thin = i1 - i0 > 2 * this.pw, d = [], pen = false, self = this;
    var col = null, lo = 0, hi = 0, loI = 0, hiI = 0;
    function put(i, y) {
      d.push((pen ? "L" : "M") + self.px(xs[i]).toFixed(2) + " " + self.py(y).toFixed(2));
      pen = true;
    }
    function flush() {
      if (col === null) return;
      if (loI <= hiI) { put(loI, lo); if (hiI !== loI) put(hiI, hi); }
      else { put(hiI, hi); put(loI, lo); }
      col = null;
    }
    for (var i = i0; i < i1; i++) {
      var b = ys[i];
      if (b === null || !isFinite(b)) { flush(); pen = false; continue; }
      if (!thin) { put(i, b); continue; }
      var c = Math.floor(this.px(xs[i]));
      if (c !== col) { flush(); col = c; lo = hi = b; loI = hiI = i; }
      else if (b < lo) { lo = b; loI = i; }
      else if (b > hi) { hi = b; hiI = i; }
    }
    flush();
    return d.join("");
  };

  Chart.prototype.drawColoured = function (s, bins) {
    var d = bins.map(function () { return []; }), lo = s.cRange[0], span = (s.cRange[1] - s.cRange[0]) || 1;
    for (var i = 0; i + 1 < s.x.length; i++) {
      var a = s.x[i], b = s.y[i], a2 = s.x[i + 1], b2 = s.y[i + 1], c = s.c[i], c2 = s.c[i + 1];
      if (a === null || b === null || a2 === null || b2 === null || c === null || c2 === null) continue;
      var k = Math.floor(((c + c2) / 2 - lo) / span * N_COLOURS);  // the top value: last bin
      k = Math.max(0, Math.min(N_COLOURS - 1, k));
      d[k].push("M" + this.px(a).toFixed(2) + " " + this.py(b).toFixed(2) + "L" +
        this.px(a2).toFixed(2) + " " + this.py(b2).toFixed(2));
    }
    bins.forEach(function (p, k) { p.setAttribute("d", d[k].join("")); });
  };

  function legend(host, series) {
    var div = document.createElement("div");
    div.className = "legend";
    series.forEach(function (s) {
      var item = document.createElement("span");
      var sw = document.createElement("span");
      sw.className = "swatch";
      if (s.c) {
        var stops = [];
        for (var k = 0; k <= 8; k++) stops.push(jet(k / 8));
        sw.className = "swatch colourbar";
        sw.style.backgroundImage = "linear-gradient(to right," + stops.join(",") + ")";
        item.appendChild(sw);
        var step = niceStep(s.cRange[1] - s.cRange[0] || 1, 20);
        item.appendChild(document.createTextNode(s.label + ": " + label(s.cRange[0], step) +
          " to " + label(s.cRange[1], step) + " " + (s.unit || "")));
        div.appendChild(item);
        return;
      }
      sw.style.borderTop = "3px " + (s.dash ? "dashed " : "solid ") + s.color;
      item.appendChild(sw);
      item.appendChild(document.createTextNode(s.label));
      div.appendChild(item);
    });
    host.appendChild(div);
  }

  function build() {
    var data = JSON.parse(document.getElementById("uwval-data").textContent);
    var charts = [];
    data.topics.forEach(function (topic, ti) {
      var host = document.getElementById("charts-" + ti);
      var timeCharts = [];
      topic.charts.forEach(function (spec, ci) {
        var box = document.createElement("div");
        box.className = "chart-box";
        var head = document.createElement("div");
        head.className = "chart-head";
        var h = document.createElement("h3");
        h.textContent = spec.title;
        head.appendChild(h);
        var buttons = {};
        [["in", "zoom in"], ["out", "zoom out"], ["reset", "reset zoom"]].forEach(function (b) {
          var btn = document.createElement("button");
          btn.type = "button";
          btn.textContent = b[1];
          btn.className = "zoom-" + b[0];
          head.appendChild(btn);
          buttons[b[0]] = btn;
        });
        box.appendChild(head);
        host.appendChild(box);
        var series = spec.series.map(function (s) {
          return { x: topic.columns[s.x], y: topic.columns[s.y], c: s.c ? topic.columns[s.c] : null,
            unit: s.unit, color: s.color, dash: s.dash, label: s.label, width: s.width };
        });
        var chart = new Chart(box, { id: "chart-" + ti + "-" + ci, title: spec.title, series: series,
          xlabel: spec.xlabel, ylabel: spec.ylabel, equal: spec.equal, height: spec.height,
          unit: spec.unit });
        legend(box, series);
        buttons.reset.addEventListener("click", function () { chart.reset(); });
        buttons["in"].addEventListener("click", function () { chart.zoomBy(0.5); });
        buttons.out.addEventListener("click", function () { chart.zoomBy(2); });
        if (!spec.equal) timeCharts.push(chart);
        charts.push(chart);
      });
      timeCharts.forEach(function (c) { c.linked = timeCharts.filter(function (o) { return o !== c; }); });
    });
    window.uwvalCharts = charts;
    document.body.setAttribute("data-ready", String(charts.length));
  }

  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", build);
  else build();
})();
