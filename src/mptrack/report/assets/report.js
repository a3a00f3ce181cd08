/* mptrack tracking report: the map (Leaflet), the track list, the time plots of the selected track
   and the summary table of every track, from the JSON in #mptrack-data.  No network needed: the map's
   background tiles load only when the browser is online; the tracks are drawn without them. */
(function () {
  "use strict";
  var D = JSON.parse(document.getElementById("mptrack-data").textContent);
  var P = D.payload;
  var PALETTE = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22",
                 "#ff7f0e", "#393b79", "#637939", "#8c6d31", "#843c39", "#7b4173", "#3182bd", "#31a354"];
  var KIND_STYLE = D.layers;  // kind -> {label, look, marker | line}: the legend, the map and the caption alike
  function colour(i) { return PALETTE[i % PALETTE.length]; }
  function el(tag, attrs, text) {
    var e = document.createElement(tag);
    for (var k in (attrs || {})) e.setAttribute(k, attrs[k]);
    if (text !== undefined) e.textContent = text;
    return e;
  }
  var SVGNS = "http://www.w3.org/2000/svg";
  function svg(tag, attrs) { var e = document.createElementNS(SVGNS, tag); for (var k in attrs) e.setAttribute(k, attrs[k]); return e; }
  function fmt(v) {
    if (v === null || v === undefined) return "—";
    if (typeof v !== "number") return String(v);
    if (!isFinite(v)) return "—";
    if (Number.isInteger(v)) return String(v);
    return Number(v.toPrecision(4)).toString();
  }

  /* ---- decoding ---- */
  function cumsum(a) { var out = new Array(a.length), s = 0; for (var i = 0; i < a.length; i++) { s += a[i]; out[i] = s; } return out; }
  function decode(tr) {
    if (tr.pts) return tr;
    var y = cumsum(tr.y || []), x = cumsum(tr.x || []), sc = P.scale;
    tr.pts = y.map(function (v, i) { return [v / sc, x[i] / sc]; });
    tr.time = cumsum(tr.t || []).map(function (v) { return v / 1000; });  // milliseconds -> s
    function rel(dy, dx) {
      if (!dy) return null;
      return dy.map(function (v, i) { return v === null || dx[i] === null ? null : [(y[i] + v) / sc, (x[i] + dx[i]) / sc]; });
    }
    tr.meas = rel(tr.my, tr.mx);
    tr.truth = rel(tr.ty, tr.tx);
    return tr;
  }

  /* ---- the map ---- */
  var mapOpts = {preferCanvas: true, worldCopyJump: false, zoomSnap: 0.25};
  if (!P.geo) { mapOpts.crs = L.CRS.Simple; mapOpts.minZoom = -12; }
  var map = L.map("map", mapOpts);
  var renderer = L.canvas({padding: 0.3, tolerance: 4});
  if (P.geo && navigator.onLine !== false) {
    L.tileLayer("https://tile.openstreetmap.org/{z}/{x}/{y}.png", {
      maxZoom: 19, attribution: "&copy; OpenStreetMap contributors"}).addTo(map);
  }
  var kinds = {};  // kind -> shown?
  Object.keys(KIND_STYLE).forEach(function (k) { kinds[k] = (D.kinds[k] || {}).on === true; });
  var tracks = P.tracks;
  var byId = {};
  var trackLayers = {};  // id -> L.featureGroup (estimate + enabled sublayers)
  var sub = {};          // id -> {kind: layer}
  var selected = null;

  function segments(tr) {
    var segs = [], cur = [], gaps = {};
    (tr.gap || []).forEach(function (i) { gaps[i] = true; });
    for (var i = 0; i < tr.pts.length; i++) {
      if ((gaps[i] || tr.f[i] === "r") && cur.length) { segs.push(cur); cur = []; }
      cur.push(tr.pts[i]);
    }
    if (cur.length) segs.push(cur);
    return segs;
  }
  function dots(points, style) {
    var g = L.layerGroup();
    points.forEach(function (p) { g.addLayer(L.circleMarker(p, L.extend({renderer: renderer, interactive: false}, style))); });
    return g;
  }
  function buildKind(tr, kind) {
    decode(tr);
    var i, pts = [], st = KIND_STYLE[kind];
    if (kind === "raw" && tr.meas) {
      for (i = 0; i < tr.meas.length; i++) if (tr.meas[i] && tr.f[i] !== "o") pts.push(tr.meas[i]);
    } else if (kind === "rejected" && tr.meas) {
      for (i = 0; i < tr.meas.length; i++) if (tr.meas[i] && tr.f[i] === "o") pts.push(tr.meas[i]);
    } else if (kind === "resets") {
      for (i = 0; i < tr.pts.length; i++) if (tr.f[i] === "r") pts.push(tr.pts[i]);
    } else if (kind === "gaps") {
      (tr.gap || []).forEach(function (j) { pts.push(tr.pts[j]); });
    } else if (kind === "truth" && tr.truth) {
      var segs = [], cur = [];
      tr.truth.forEach(function (p) { if (p) cur.push(p); else if (cur.length) { segs.push(cur); cur = []; } });
      if (cur.length) segs.push(cur);
      return L.polyline(segs, L.extend({renderer: renderer, interactive: false}, st.line));
    } else if (kind === "ellipses" && tr.ell) {
      return ellipses(tr);
    } else {
      return null;
    }
    return dots(pts, st.marker);
  }
  function ellipses(tr) {
    var g = L.layerGroup(), n = tr.pts.length, step = Math.max(1, Math.ceil(n / 400));
    for (var i = 0; i < n; i += step) {
      var a = tr.ell[0][i], b = tr.ell[1][i], az = tr.ell[2][i];
      if (a === null || b === null || az === null) continue;
      var ring = [], th = az * Math.PI / 180, c = tr.pts[i];
      for (var k = 0; k <= 24; k++) {
        var u = 2 * Math.PI * k / 24, p = a * Math.cos(u), q = b * Math.sin(u);
        var e = p * Math.sin(th) + q * Math.cos(th), nn = p * Math.cos(th) - q * Math.sin(th);
        ring.push(P.geo ? [c[0] + nn / 111320, c[1] + e / (111320 * Math.cos(c[0] * Math.PI / 180))]
                        : [c[0] + nn, c[1] + e]);
      }
      g.addLayer(L.polygon(ring, L.extend({renderer: renderer, interactive: false}, KIND_STYLE.ellipses.line)));
    }
    return g;
  }
  function syncKind(tr, kind) {
    var s = sub[tr.id], group = trackLayers[tr.id];
    var want = kinds[kind] && (kind !== "ellipses" || selected === tr.id);
    if (want && !s[kind]) { s[kind] = buildKind(tr, kind); }
    if (!s[kind]) return;
    if (want && !group.hasLayer(s[kind])) group.addLayer(s[kind]);
    if (!want && group.hasLayer(s[kind])) group.removeLayer(s[kind]);
  }
  var bounds = L.latLngBounds([]);
  tracks.forEach(function (tr, i) {
    byId[tr.id] = tr;
    tr.colour = colour(i);
    sub[tr.id] = {};
    var group = L.featureGroup();
    trackLayers[tr.id] = group;
    if (!tr.drawn) return;
    decode(tr);
    var line = L.polyline(segments(tr), {renderer: renderer, color: tr.colour, weight: 3, opacity: 0.9});
    line.bindTooltip(tr.id, {sticky: true});
    line.on("click", function () { select(tr.id, false); });
    group.addLayer(line);
    sub[tr.id].estimate = line;
    bounds.extend(line.getBounds());
  });
  function showTrack(id, on) {
    var g = trackLayers[id];
    if (on && !map.hasLayer(g)) {
      g.addTo(map);
      Object.keys(KIND_STYLE).forEach(function (k) { syncKind(byId[id], k); });
      if (sub[id].estimate) sub[id].estimate.bringToFront();
    }
    if (!on && map.hasLayer(g)) map.removeLayer(g);
  }
  tracks.forEach(function (tr) { showTrack(tr.id, true); });
  if (bounds.isValid()) map.fitBounds(bounds, {padding: [20, 20]}); else map.setView([0, 0], 2);
  L.control.scale({imperial: false, maxWidth: 150}).addTo(map);  // metres (local x/y: the same units)

  /* ---- layer switches: each with a swatch drawn from the layer's own style (as on the map) ---- */
  function swatch(st) {
    var box = svg("svg", {width: 16, height: 16, viewBox: "0 0 16 16", "class": "swatch-svg", "aria-hidden": "true"});
    if (st.marker) {
      var m = st.marker;
      box.appendChild(svg("circle", {cx: 8, cy: 8, r: Math.min(Math.max(m.radius, 3), 6), stroke: m.color, "stroke-width": m.weight || 0,
                                     fill: m.fill === false ? "none" : (m.fillColor || m.color),
                                     "fill-opacity": m.fill === false ? 0 : (m.fillOpacity === undefined ? 0.2 : m.fillOpacity)}));
    } else if (st.shape === "ellipse") {
      box.appendChild(svg("ellipse", {cx: 8, cy: 8, rx: 7, ry: 4, stroke: st.line.color, "stroke-width": st.line.weight,
                                      fill: st.line.color, "fill-opacity": st.line.fillOpacity}));
    } else {
      box.appendChild(svg("line", {x1: 1, y1: 8, x2: 15, y2: 8, stroke: st.line.color, "stroke-width": st.line.weight,
                                   "stroke-dasharray": st.line.dashArray || ""}));
    }
    return box;
  }
  var panel = document.getElementById("layers");
  Object.keys(KIND_STYLE).forEach(function (kind) {
    var info = D.kinds[kind];
    if (!info) return;
    var lab = el("label", {"class": "kind"});
    var box = el("input", {type: "checkbox", "data-kind": kind});
    box.checked = kinds[kind];
    box.addEventListener("change", function () {
      kinds[kind] = box.checked;
      tracks.forEach(function (tr) {
        if (!map.hasLayer(trackLayers[tr.id])) return;
        syncKind(tr, kind);
        if (sub[tr.id].estimate) sub[tr.id].estimate.bringToFront();
      });
    });
    lab.appendChild(box);
    lab.appendChild(swatch(KIND_STYLE[kind]));
    lab.appendChild(document.createTextNode(" " + KIND_STYLE[kind].label + " (" + info.text + ")"));
    panel.appendChild(lab);
  });

  /* ---- the track list ---- */
  var list = document.getElementById("track-list");
  var items = {};
  tracks.forEach(function (tr) {
    var li = el("li", {"data-track": tr.id});
    var box = el("input", {type: "checkbox", title: "show / hide"});
    box.checked = true;
    box.addEventListener("change", function () { showTrack(tr.id, box.checked); });
    var sw = el("span", {"class": "swatch"});
    sw.style.background = tr.colour;
    var name = el("a", {href: "#", "class": "track-name"}, tr.id);
    name.addEventListener("click", function (ev) { ev.preventDefault(); select(tr.id, true); });
    li.appendChild(box); li.appendChild(sw); li.appendChild(name);
    li.appendChild(el("span", {"class": "count"}, " " + tr.n + " pts"));
    list.appendChild(li);
    items[tr.id] = {li: li, box: box};
  });
  document.getElementById("track-filter").addEventListener("input", function (ev) {
    var q = ev.target.value.toLowerCase();
    tracks.forEach(function (tr) { items[tr.id].li.style.display = tr.id.toLowerCase().indexOf(q) >= 0 ? "" : "none"; });
  });
  function setAll(on) {
    tracks.forEach(function (tr) {
      if (items[tr.id].li.style.display === "none") return;
      items[tr.id].box.checked = on; showTrack(tr.id, on);
    });
  }
  document.getElementById("show-all").addEventListener("click", function () { setAll(true); });
  document.getElementById("hide-all").addEventListener("click", function () { setAll(false); });

  /* ---- time plots of the selected track ---- */
  var MAX_INTERVALS = 6;  // a log axis has at most this many intervals between labels (decades thinned)
  function ticks(lo, hi, log, every) {
    var out = [];
    if (log) {
      for (var p = Math.floor(Math.log10(lo)); p <= Math.ceil(Math.log10(hi)); p++) {
        var v = Math.pow(10, p);
        [1, 2, 5].forEach(function (m) {
          if (m * v >= lo * 0.999 && m * v <= hi * 1.001) out.push(m * v);
        });
      }
      // the bounds are labels (see logBounds): every `every`-th decade over two decades or more, else 1-2-5
      var first = Math.round(Math.log10(lo));
      var decades = out.filter(function (v) {
        var e = Math.log10(v);
        return Math.abs(e - Math.round(e)) < 1e-9 && (Math.round(e) - first) % (every || 1) === 0;
      });
      return Math.log10(hi / lo) >= 2 - 1e-9 && decades.length >= 2 ? decades : out.length >= 2 ? out : ticks(lo, hi, false);
    }
    var span = hi - lo || 1, step = linearStep(lo, hi);
    for (var t = Math.ceil(lo / step) * step; t <= hi + 1e-9 * span; t += step) out.push(t);
    return out;
  }
  function linearStep(lo, hi) {  // 1, 2 or 5 times a power of ten, 4 to 10 steps from lo to hi
    var span = hi - lo || 1, step = Math.pow(10, Math.floor(Math.log10(span / 4)));
    if (span / step > 10) step *= 2;
    if (span / step > 10) step *= 2.5;
    return step;
  }
  function nice125(v, up) {  // the nearest 1, 2 or 5 times a power of ten below (or above) v > 0
    var p = Math.pow(10, Math.floor(Math.log10(v))), m = [1, 2, 5, 10];
    if (up) { for (var i = 0; i < m.length; i++) if (m[i] * p >= v * (1 - 1e-9)) return m[i] * p; }
    for (var j = m.length - 1; j >= 0; j--) if (m[j] * p <= v * (1 + 1e-9)) return m[j] * p;
    return v;
  }
  function logBounds(lo, hi) {  // [low, high, decades per label]: from a label to a label, every value between two
    var a = nice125(lo, false), b = nice125(hi, true);
    if (Math.log10(b / a) < 2) return [a, b, 0];  // labels at 1, 2 and 5 times powers of ten
    var p = Math.floor(Math.log10(lo) + 1e-9), q = Math.ceil(Math.log10(hi) - 1e-9);
    var every = Math.max(1, Math.ceil((q - p) / MAX_INTERVALS));
    return [Math.pow(10, p), Math.pow(10, p + every * Math.ceil((q - p) / every)), every];  // decades
  }
  var SUPER = {"-": "\u207b", "0": "\u2070", "1": "\u00b9", "2": "\u00b2", "3": "\u00b3", "4": "\u2074",
               "5": "\u2075", "6": "\u2076", "7": "\u2077", "8": "\u2078", "9": "\u2079"};
  function tickLabel(v) {  // short at any magnitude: 0.01, 500, 10⁶, 2×10⁻⁵
    if (v === 0 || !isFinite(v)) return fmt(v);
    var e = Math.floor(Math.log10(Math.abs(v)) + 1e-9);
    if (e >= -3 && e <= 4) return fmt(v);
    var m = Number((v / Math.pow(10, e)).toPrecision(3));
    return (m === 1 ? "" : m === -1 ? "-" : fmt(m) + "\u00d7") + "10" + String(e).split("").map(function (c) { return SUPER[c]; }).join("");
  }
  var TIME_UNITS = [[7200, 3600, "h"], [120, 60, "min"], [0, 1, "s"]];  // [from a span of, seconds per unit, name]
  function plot(spec) {
    var W = 560, H = 190, L0 = 58, R0 = 10, T0 = 22, B0 = 34;
    var s = svg("svg", {viewBox: "0 0 " + W + " " + H, "class": "plot", role: "img", "aria-label": spec.title});
    var xs = spec.x, ys = spec.y, xmin = Infinity, xmax = -Infinity, ymin = Infinity, ymax = -Infinity, i;
    for (i = 0; i < xs.length; i++) {
      var v = ys[i];
      if (v === null || !isFinite(v) || (spec.log && v <= 0)) continue;
      xmin = Math.min(xmin, xs[i]); xmax = Math.max(xmax, xs[i]); ymin = Math.min(ymin, v); ymax = Math.max(ymax, v);
    }
    if (spec.band) { ymin = Math.min(ymin, spec.band[0]); ymax = Math.max(ymax, spec.band[1]); }
    if (spec.floor !== undefined) ymin = Math.max(ymin, spec.floor);
    if (!isFinite(xmin)) { s.appendChild(svg("text", {x: W / 2, y: H / 2, "text-anchor": "middle"})).textContent = "no values"; return s; }
    if (spec.xr) { xmin = spec.xr[0]; xmax = spec.xr[1]; }  // every plot of a track on the same time axis
    var xs0 = spec.xr ? spec.xr[0] : xmin;  // the track's first point: time 0 of the axis
    if (!spec.log) { ymin = Math.min(0, ymin); }
    if (ymax <= ymin) {  // a constant series: in the middle of the plot, between two labels
      if (spec.log) { ymin = ymin / 2; ymax = ymax * 2; } else { ymin = ymin - 1; ymax = ymax + 1; }
    }
    var every = 0;
    if (spec.log) { var lb = logBounds(ymin, ymax); ymin = lb[0]; ymax = lb[1]; every = lb[2]; } else {
      var st = linearStep(ymin, ymax);  // from a label to a label
      ymin = Math.floor(ymin / st + 1e-9) * st; ymax = Math.ceil(ymax / st - 1e-9) * st;
    }
    if (xmax <= xmin) xmax = xmin + 1;
    var unit = TIME_UNITS.filter(function (u) { return xmax - xmin >= u[0]; })[0];
    var ly = spec.log ? Math.log10 : function (v) { return v; };
    var a = ly(ymin), b = ly(ymax);
    function X(v) { return L0 + (v - xmin) / (xmax - xmin) * (W - L0 - R0); }
    function Y(v) { return H - B0 - (ly(Math.min(Math.max(v, ymin), ymax)) - a) / (b - a) * (H - T0 - B0); }
    s.appendChild(svg("rect", {x: L0, y: T0, width: W - L0 - R0, height: H - T0 - B0, fill: "#fff", stroke: "#bbb"}));
    if (spec.band) {
      s.appendChild(svg("rect", {x: L0, y: Y(spec.band[1]), width: W - L0 - R0, height: Y(spec.band[0]) - Y(spec.band[1]),
                                 fill: "#2ca02c", "fill-opacity": 0.12, "class": "band"}));
    }
    ticks(ymin, ymax, spec.log, every).forEach(function (t) {
      s.appendChild(svg("line", {x1: L0 - 3, x2: L0, y1: Y(t), y2: Y(t), stroke: "#444"}));
      s.appendChild(svg("text", {x: L0 - 5, y: Y(t) + 4, "text-anchor": "end", "class": "tick"})).textContent = tickLabel(t);
    });
    ticks((xmin - xs0) / unit[1], (xmax - xs0) / unit[1], false).forEach(function (t) {
      var x = X(xs0 + t * unit[1]);
      s.appendChild(svg("line", {x1: x, x2: x, y1: H - B0, y2: H - B0 + 3, stroke: "#444"}));
      s.appendChild(svg("text", {x: x, y: H - B0 + 15, "text-anchor": "middle", "class": "tick xtick"})).textContent = tickLabel(t);
    });
    s.appendChild(svg("text", {x: (L0 + W - R0) / 2, y: H - 4, "text-anchor": "middle", "class": "axis"})).textContent =
      "time since the track's first point (" + unit[2] + ")";
    s.appendChild(svg("text", {x: L0, y: 14, "class": "title"})).textContent = spec.title;
    if (spec.dots) {
      for (i = 0; i < xs.length; i++) {
        if (ys[i] === null || (spec.log && ys[i] <= 0)) continue;
        var bad = spec.mark && spec.mark[i];
        s.appendChild(svg("circle", {cx: X(xs[i]), cy: Y(ys[i]), r: bad ? 3 : 1.8, fill: bad ? "none" : spec.colour,
                                     stroke: bad ? "#ff7f0e" : "none", "stroke-width": 1.5}));
      }
    } else {
      var d = "", pen = false;
      for (i = 0; i < xs.length; i++) {
        if (ys[i] === null || !isFinite(ys[i]) || (spec.log && ys[i] <= 0)) { pen = false; continue; }
        d += (pen ? "L" : "M") + X(xs[i]).toFixed(1) + " " + Y(ys[i]).toFixed(1);
        pen = true;
      }
      s.appendChild(svg("path", {d: d, fill: "none", stroke: spec.colour, "stroke-width": 1.4}));
    }
    return s;
  }
  function select(id, zoom) {
    var tr = byId[id];
    if (!tr) return;
    var prev = selected;
    selected = id;
    if (prev && byId[prev]) syncKind(byId[prev], "ellipses");
    if (!map.hasLayer(trackLayers[id])) { items[id].box.checked = true; showTrack(id, true); }
    syncKind(tr, "ellipses");
    if (sub[id].estimate) sub[id].estimate.bringToFront();
    Object.keys(items).forEach(function (k) { items[k].li.classList.toggle("selected", k === id); });
    if (zoom && sub[id].estimate) map.fitBounds(sub[id].estimate.getBounds(), {padding: [30, 30], maxZoom: 17});
    var box = document.getElementById("plots");
    box.textContent = "";
    if (!tr.drawn) { box.appendChild(el("p", {}, "Track " + id + " has no position to draw.")); return; }
    decode(tr);
    var shown = [], xr = [tr.time[0], tr.time[tr.time.length - 1]];
    if (tr.sp) { box.appendChild(plot({title: "speed (m/s)", x: tr.time, y: tr.sp, colour: tr.colour, xr: xr})); shown.push("speed"); }
    box.appendChild(plot({title: "1-σ position uncertainty (m)", x: tr.time, y: tr.sd, colour: tr.colour, log: true, xr: xr}));
    shown.push("1-σ position uncertainty sqrt(var_east + var_north)");
    if (tr.nis) {
      var band = tr.dof ? P.bands[String(tr.dof)] : null;
      var rejected = tr.nis.map(function (v, i) { return tr.f[i] === "o"; });
      var floor = band ? Math.pow(10, Math.floor(Math.log10(band[0] / 100))) : undefined;  // the axis starts there
      var low = band && tr.nis.some(function (v) { return v !== null && v < floor; });
      box.appendChild(plot({title: "NIS" + (band ? " with its 95 % χ² band (" + tr.dof + " dof)" : ""), x: tr.time, y: tr.nis,
                            colour: tr.colour, log: true, dots: true, band: band, mark: rejected, floor: floor, xr: xr}));
      shown.push("NIS of every fix" + (band ? " against the 95 % χ² band of " + tr.dof + " degrees of freedom (green)" : "")
                 + (rejected.some(Boolean) ? ", fixes rejected by the gate as orange rings" : "")
                 + (low ? "; values below " + tickLabel(floor) + " are drawn on the axis" : ""));
    }
    if (tr.err) { box.appendChild(plot({title: "error against truth (m)", x: tr.time, y: tr.err, colour: "#d62728", log: true, xr: xr})); shown.push("error against truth"); }
    var cap = "Track " + id + ": " + shown.join("; ") + ". " + tr.drawn + " of " + tr.n + " points drawn"
              + (tr.drawn < tr.n ? " (every k-th point; rejected fixes thinned alike)" : "") + ".";
    document.getElementById("plots-caption").textContent = cap;
    document.getElementById("plots-track").textContent = id;
  }

  /* ---- the summary table (every track; sortable, paginated) ---- */
  var S = D.summary, PAGE = 50, page = 0, sortCol = -1, sortDir = 1, filter = "";
  var rows = S.rows.slice();
  var tbl = document.getElementById("summary");
  function renderTable() {
    var shown = rows.filter(function (r) { return !filter || String(r[0]).toLowerCase().indexOf(filter) >= 0; });
    var pages = Math.max(1, Math.ceil(shown.length / PAGE));
    page = Math.min(page, pages - 1);
    tbl.textContent = "";
    var thead = el("thead"), tr = el("tr");
    S.columns.forEach(function (c, j) {
      var th = el("th", {"data-col": j, title: "sort by " + c}, c + (j === sortCol ? (sortDir > 0 ? " ▲" : " ▼") : ""));
      th.addEventListener("click", function () {
        if (sortCol === j) sortDir = -sortDir; else { sortCol = j; sortDir = 1; }
        rows.sort(function (a, b) {
          var x = a[j], y = b[j];
          if (x === y) return 0;
          if (x === null || x === undefined) return 1;
          if (y === null || y === undefined) return -1;
          return (x < y ? -1 : 1) * sortDir;
        });
        page = 0; renderTable();
      });
      tr.appendChild(th);
    });
    thead.appendChild(tr); tbl.appendChild(thead);
    var tbody = el("tbody");
    function addRow(r, cls) {
      var row = el("tr", cls ? {"class": cls} : {});
      r.forEach(function (v, j) {
        var td = el("td", {}, j === 0 ? "" : fmt(v));
        if (j === 0) {
          if (cls) td.textContent = v;
          else { var a = el("a", {href: "#map-section"}, v); a.addEventListener("click", function () { select(v, true); }); td.appendChild(a); }
        }
        row.appendChild(td);
      });
      tbody.appendChild(row);
    }
    if (S.overall) addRow(S.overall, "overall");
    shown.slice(page * PAGE, (page + 1) * PAGE).forEach(function (r) { addRow(r); });
    tbl.appendChild(tbody);
    document.getElementById("page-info").textContent = "page " + (page + 1) + " of " + pages + " (" + shown.length
      + " of " + rows.length + " tracks)";
    document.getElementById("prev-page").disabled = page === 0;
    document.getElementById("next-page").disabled = page >= pages - 1;
  }
  document.getElementById("prev-page").addEventListener("click", function () { page--; renderTable(); });
  document.getElementById("next-page").addEventListener("click", function () { page++; renderTable(); });
  document.getElementById("table-filter").addEventListener("input", function (ev) { filter = ev.target.value.toLowerCase(); page = 0; renderTable(); });
  renderTable();

  if (tracks.length) select(tracks[0].id, false);
  /* what a test (or a curious reader) can check after loading: tracks listed and layers on the map */
  window.mptrackReport = {map: map, trackLayers: trackLayers, select: select};
  var onMap = 0;
  Object.keys(trackLayers).forEach(function (k) { if (map.hasLayer(trackLayers[k])) onMap++; });
  document.body.setAttribute("data-track-layers", String(onMap));
  document.body.setAttribute("data-ready", "1");
})();
