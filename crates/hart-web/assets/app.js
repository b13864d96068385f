// hartkit web dashboard: keeps the pages live. The server renders every page whole;
// this script only updates values (plant and device pages, from /api/events) and
// fills the traffic table (from /api/traffic). No libraries, nothing from elsewhere.
"use strict";

function text(v, digits) {
  return (typeof v === "number") ? v.toFixed(digits) : "—";
}

function esc(s) {
  return String(s === null || s === undefined ? "" : s).replace(/[&<>"']/g, function (c) {
    return { "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" }[c];
  });
}

function statusWords(d) {
  var w = d.device_status_set || [];
  return w.length ? w.join(", ") : "ok";
}

// One row of the plant table: the same cells as the server's.
function plantRow(d) {
  var pct = d.percent_of_range;
  var bar = (typeof pct === "number")
    ? '<meter class="bar" min="0" max="100" value="' + Math.max(0, Math.min(100, pct)).toFixed(1) + '"></meter>' : "";
  var pv = d.pv || {};
  return '<tr id="dev-' + d.unit + '" data-unit="' + d.unit + '"><td>' + d.unit + '</td>' +
    '<td><a href="/device/' + d.unit + '" class="tag">' + esc(d.name) + '</a><div class="muted small">' + esc(d.descriptor) + '</div></td>' +
    '<td>' + esc(d.loop) + '</td><td>' + (d.polling_address === null ? "—" : d.polling_address) + '</td>' +
    '<td class="muted small">' + esc(d.unique_id) + '</td>' +
    '<td class="num pv">' + text(pv.value, 3) + '</td><td class="units">' + esc(pv.units_symbol) + '</td>' +
    '<td class="pct">' + bar + '<span class="small">' + (typeof pct === "number" ? pct.toFixed(1) + " %" : "") + '</span></td>' +
    '<td class="num current">' + (typeof d.loop_current === "number" ? d.loop_current.toFixed(3) + " mA" : "—") + '</td>' +
    '<td class="status">' + esc(statusWords(d)) + '</td>' +
    '<td><span class="q q-' + esc(d.quality) + '">' + esc(d.quality) + '</span></td>' +
    '<td class="num age">' + (d.age_s === null ? "—" : d.age_s + " s") + '</td></tr>';
}

function setField(root, name, value) {
  var el = root.querySelector('[data-field="' + name + '"]');
  if (el && el.textContent !== value) { el.textContent = value; }
}

function live(onPlant) {
  var state = document.getElementById("live");
  var es = new EventSource("/api/events");
  es.addEventListener("plant", function (e) {
    var plant = JSON.parse(e.data);
    if (state) { state.textContent = "on"; }
    var up = document.getElementById("updated");
    if (up) { up.textContent = plant.time; }
    onPlant(plant);
  });
  es.onerror = function () { if (state) { state.textContent = "reconnecting…"; } };
}

function plantPage() {
  var body = document.querySelector("#plant tbody");
  // Rows are updated cell by cell, so what the user points at (a tag's link, a selection)
  // stays the same element while its values change; only a changed set of devices
  // rebuilds the table.
  live(function (plant) {
    var fresh = document.createElement("tbody");
    fresh.innerHTML = plant.devices.map(plantRow).join("");
    var same = body.rows.length === fresh.rows.length;
    for (var i = 0; same && i < fresh.rows.length; i++) { same = body.rows[i].id === fresh.rows[i].id; }
    if (!same) { body.innerHTML = fresh.innerHTML; return; }
    for (var r = 0; r < fresh.rows.length; r++) {
      var now = body.rows[r].cells, next = fresh.rows[r].cells;
      if (now.length !== next.length) { body.rows[r].innerHTML = fresh.rows[r].innerHTML; continue; }
      for (var c = 0; c < next.length; c++) {
        if (now[c].innerHTML !== next[c].innerHTML) {
          now[c].innerHTML = next[c].innerHTML;
          now[c].className = next[c].className;
        }
      }
    }
  });
}

function devicePage() {
  var values = document.getElementById("values");
  if (!values) { return; }
  var unit = Number(values.dataset.unit);
  live(function (plant) {
    var d = plant.devices.filter(function (x) { return x.unit === unit; })[0];
    if (!d) { return; }
    ["pv", "sv", "tv", "qv"].forEach(function (k) {
      var v = d[k] || {};
      setField(values, k, text(v.value, 3));
      setField(values, k + "_units", v.units_symbol || "");
    });
    setField(values, "loop_current", text(d.loop_current, 3));
    setField(values, "percent_of_range", text(d.percent_of_range, 1));
    setField(document, "status", statusWords(d));
    var q = document.querySelector('h1 [data-field="quality"]');
    if (q) { q.textContent = d.quality; q.className = "q q-" + d.quality; }
  });
  // The trend is drawn by the server: fetch it again now and then.
  var img = document.getElementById("trend");
  if (img) {
    var base = img.getAttribute("src").split("&t=")[0];
    setInterval(function () { img.src = base + "&t=" + Date.now(); }, 10000);
  }
}

function trafficPage() {
  var form = document.getElementById("traffic-filter");
  var body = document.querySelector("#traffic tbody");
  var info = document.getElementById("traffic-state");
  var download = document.getElementById("download");
  var pause = document.getElementById("pause");
  var after = 0, paused = false, busy = false;
  function query() {
    var q = [];
    ["loop", "device", "command"].forEach(function (k) {
      var v = form.elements[k].value.trim();
      if (v !== "") { q.push(k + "=" + encodeURIComponent(v)); }
    });
    return q.join("&");
  }
  function restart() {
    after = 0; body.innerHTML = "";
    download.href = "/api/traffic.pcapng" + (query() ? "?" + query() : "");
    poll();
  }
  function row(f) {
    var fr = f.frame || {};
    var cmd = (fr.command === undefined ? "" : fr.command) + (f.title ? " " + f.title : "");
    return '<tr class="' + esc(f.kind) + '"><td>' + f.seq + '</td><td>' + esc(f.time.slice(11, 23)) + '</td><td>' +
      esc(f.loop) + '</td><td>' + esc(f.kind) + '</td><td>' + esc(f.text) + '</td><td>' + esc(cmd) + '</td></tr>';
  }
  function poll() {
    if (paused || busy) { return; }
    busy = true;
    var q = query();
    fetch("/api/traffic?limit=500&after=" + after + (q ? "&" + q : ""))
      .then(function (r) { return r.json(); })
      .then(function (t) {
        busy = false;
        if (t.error) { info.textContent = t.error; return; }
        if (t.frames.length) {
          body.insertAdjacentHTML("beforeend", t.frames.map(row).join(""));
          while (body.rows.length > 1000) { body.deleteRow(0); }
        }
        after = t.last_seq;
        info.textContent = t.lost ? t.lost + " frames came too fast to keep" : "";
      })
      .catch(function () { busy = false; info.textContent = "the gateway does not answer"; });
  }
  form.addEventListener("change", restart);
  form.addEventListener("submit", function (e) { e.preventDefault(); restart(); });
  pause.addEventListener("click", function () {
    paused = !paused;
    pause.textContent = paused ? "Resume" : "Pause";
    if (!paused) { poll(); }
  });
  restart();
  setInterval(poll, 1000);
}

document.addEventListener("DOMContentLoaded", function () {
  var page = document.body.dataset.page;
  if (page === "plant") { plantPage(); }
  if (page === "device") { devicePage(); }
  if (page === "traffic") { trafficPage(); }
});
