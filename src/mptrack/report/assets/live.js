/* mptrack live map: devices from /api/devices, then every accepted fix from /api/stream (Server-Sent
   Events).  Each device shows its estimate (a marker with its 1-sigma ellipse) and its last raw fix;
   clicking it draws its last hour (/api/devices/ID/track); a small fleet's markers carry their names (a
   name that would cover another is hidden until the view separates them).
   Works offline: the background tiles load only when the browser is online.  The page reports its state
   on <body>: data-devices (markers on the map), data-events (fixes received), data-names-shown, data-ready. */
(function () {
  "use strict";
  var CFG = JSON.parse(document.getElementById("mptrack-live").textContent);
  function url(path, params) {
    var q = Object.assign({}, params || {});
    if (CFG.key) q.key = CFG.key;
    var s = Object.keys(q).map(function (k) { return encodeURIComponent(k) + "=" + encodeURIComponent(q[k]); }).join("&");
    return path + (s ? "?" + s : "");
  }
  var map = L.map("map", {preferCanvas: true, zoomSnap: 0.25, worldCopyJump: true});
  if (navigator.onLine !== false) {
    L.tileLayer("https://tile.openstreetmap.org/{z}/{x}/{y}.png", {
      maxZoom: 19, attribution: "&copy; OpenStreetMap contributors"}).addTo(map);
  }
  L.control.scale({imperial: false}).addTo(map);
  map.setView([20, 0], 2);
  var devices = {};   // id -> {marker, raw, ellipse, item, details, track, named}
  // up to this many devices, each is named on the map beside its marker (more names would cover it);
  // beyond, a marker's name and last fix show when the pointer is on it, as the list shows them
  var NAMED_UP_TO = 30;
  var events = 0, fitted = false;
  var list = document.getElementById("device-list");

  function ellipsePoints(lat, lon, major, minor, azDeg) {
    // the 1-sigma ellipse as a polygon (metres -> degrees on a local tangent plane)
    var pts = [], az = azDeg * Math.PI / 180, mLat = 111320, mLon = 111320 * Math.cos(lat * Math.PI / 180);
    for (var i = 0; i < 36; i++) {
      var a = 2 * Math.PI * i / 36, x = major * Math.cos(a), y = minor * Math.sin(a);
      var e = x * Math.sin(az) + y * Math.cos(az), n = x * Math.cos(az) - y * Math.sin(az);
      pts.push([lat + n / mLat, lon + e / Math.max(mLon, 1e-6)]);
    }
    return pts;
  }
  function details(d) {
    return (d.time ? d.time.replace("T", " ").replace(".000Z", "Z") : "") + (d.flag ? " · " + d.flag : "") +
      (d.ell_major_m != null ? " · ±" + d.ell_major_m.toPrecision(2) + " m" : "");
  }
  function text(d) { return d.id + " · " + details(d); }
  // names that would cover one another: each one that overlaps a name shown before it is hidden (its device
  // stays in the list); checked once a frame after names move or the view changes
  var declutterDue = false;
  function declutter() {
    if (declutterDue) return;
    declutterDue = true;
    requestAnimationFrame(function () {
      declutterDue = false;
      var shown = [];   // {r: the name's box, el, more: names it hides}
      Object.keys(devices).forEach(function (id) {
        var tip = devices[id].named && devices[id].marker.getTooltip(), el = tip && tip.getElement();
        if (!el) return;
        el.removeAttribute("data-more");
        var r = el.getBoundingClientRect();
        var under = shown.filter(function (s) {
          return r.left < s.r.right && s.r.left < r.right && r.top < s.r.bottom && s.r.top < r.bottom;
        })[0];
        el.style.visibility = under ? "hidden" : "";
        if (under) under.more += 1; else shown.push({r: r, el: el, more: 0});
      });
      shown.forEach(function (s) { if (s.more) s.el.setAttribute("data-more", "+" + s.more); });   // "van-a +2"
      document.body.setAttribute("data-names-shown", String(shown.length));
    });
  }
  map.on("zoomend moveend", declutter);
  function update(d) {
    if (d.lat == null || d.lon == null) return;
    var dev = devices[d.id];
    if (!dev) {
      dev = devices[d.id] = {
        marker: L.circleMarker([d.lat, d.lon], {radius: 6, color: "#1f77b4", fillOpacity: 0.9, weight: 2}).addTo(map),
        raw: L.circleMarker([d.lat, d.lon], {radius: 3, color: "#777", fillOpacity: 0.6, weight: 1}).addTo(map),
        ellipse: L.polygon([[d.lat, d.lon]], {color: "#1f77b4", weight: 1, fillOpacity: 0.08}).addTo(map),
        item: document.createElement("li")
      };
      // the id on its line, the time, flag and uncertainty below it (one line was wider than the list)
      dev.item.appendChild(document.createElement("b")).textContent = d.id;
      dev.details = dev.item.appendChild(document.createElement("small"));
      dev.marker.on("click", function () { showTrack(d.id); });
      dev.item.addEventListener("click", function () { showTrack(d.id); map.panTo(dev.marker.getLatLng()); });
      list.appendChild(dev.item);
      var count = Object.keys(devices).length;
      document.getElementById("device-count").textContent = count;
      document.body.setAttribute("data-devices", String(count));
      if (count === NAMED_UP_TO + 1) {   // too many names now: every marker's name on hover only
        Object.keys(devices).forEach(function (id) {
          var other = devices[id];
          if (other.named) { other.marker.unbindTooltip().bindTooltip(id); other.named = false; }
        });
      }
    }
    dev.marker.setLatLng([d.lat, d.lon]);
    if (d.raw_lat != null) dev.raw.setLatLng([d.raw_lat, d.raw_lon]);
    if (d.ell_major_m != null) dev.ellipse.setLatLngs(ellipsePoints(d.lat, d.lon, d.ell_major_m, d.ell_minor_m, d.ell_azimuth_deg || 0));
    if (Object.keys(devices).length <= NAMED_UP_TO) {
      if (!dev.named) {
        dev.marker.unbindTooltip().bindTooltip(d.id, {permanent: true, direction: "right", offset: [8, 0],
                                                      className: "device-name"});
        dev.named = true;
      }
      declutter();
    } else {
      dev.marker.unbindTooltip().bindTooltip(text(d));
    }
    dev.details.textContent = details(d);
  }
  function showTrack(id) {
    var from = new Date(Date.now() - 3600e3).toISOString();
    fetch(url("/api/devices/" + encodeURIComponent(id) + "/track", {from: from, format: "json"}))
      .then(function (r) { return r.json(); })
      .then(function (rows) {
        var dev = devices[id];
        if (!dev) return;
        if (dev.track) dev.track.remove();
        var est = rows.filter(function (r) { return r.lat != null; }).map(function (r) { return [r.lat, r.lon]; });
        var raw = rows.map(function (r) { return [r.meas_lat, r.meas_lon]; });
        dev.track = L.layerGroup([
          L.polyline(est, {color: "#1f77b4", weight: 3}),
          L.layerGroup(raw.map(function (p) { return L.circleMarker(p, {radius: 2, color: "#777", weight: 1}); }))
        ]).addTo(map);
        document.body.setAttribute("data-track-points", String(rows.length));
      });
  }
  document.getElementById("device-filter").addEventListener("input", function (e) {
    var f = e.target.value.toLowerCase();
    Object.keys(devices).forEach(function (id) {
      devices[id].item.style.display = id.toLowerCase().indexOf(f) >= 0 ? "" : "none";
    });
  });
  fetch(url("/api/devices")).then(function (r) { return r.json(); }).then(function (rows) {
    rows.forEach(function (d) { d.time = d.last_fix_time; update(d); });
    var pts = rows.filter(function (d) { return d.lat != null; }).map(function (d) { return [d.lat, d.lon]; });
    // the first view is placed, not animated (a screenshot taken at once, as chromium --screenshot does, caught
    // the zoom half-way: the markers' canvas scaled and blurred)
    if (pts.length) { map.fitBounds(L.latLngBounds(pts).pad(0.2), {maxZoom: 16, animate: false}); fitted = true; }
    document.body.setAttribute("data-ready", "1");
  });
  var source = new EventSource(url("/api/stream"));
  source.onopen = function () { document.getElementById("status").textContent = "live"; };
  source.onerror = function () { document.getElementById("status").textContent = "reconnecting…"; };
  source.addEventListener("fix", function (e) {
    var d = JSON.parse(e.data);
    update({id: d.device, time: d.time, lat: d.lat, lon: d.lon, raw_lat: d.raw_lat, raw_lon: d.raw_lon,
            ell_major_m: d.ell_major_m, ell_minor_m: d.ell_minor_m, ell_azimuth_deg: d.ell_azimuth_deg, flag: d.flag});
    events += 1;
    document.body.setAttribute("data-events", String(events));
    if (!fitted) { map.setView([d.lat, d.lon], 15, {animate: false}); fitted = true; }
  });
})();
