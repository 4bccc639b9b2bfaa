// The interactive parts of report.html (experiments/report_html.py inlines this file): sortable
// tables, rate-quality charts as inline SVG, one image viewer per scene, and #status, which
// records script errors, image loads and (with #selftest in the URL) a self-test of the viewer
// and of a table sort for tests/python/test_report_html.py. No library, no network.
(function () {
  "use strict";
  var status = document.getElementById("status");
  var errors = [];
  function setStatus(k, v) { status.setAttribute("data-" + k, String(v)); }
  function noteError(msg) {
    errors.push(String(msg));
    setStatus("errors", errors.length);
    setStatus("error-messages", errors.join(" | ").slice(0, 2000));
  }
  window.onerror = function (msg, src, line) { noteError(msg + " (line " + line + ")"); };
  window.addEventListener("unhandledrejection", function (e) { noteError("unhandled rejection: " + e.reason); });

  // Every image the page shows or can switch to, loaded once here and counted.
  var expected = {}, loaded = {}, failed = {};
  function size(o) { return Object.keys(o).length; }
  function countImages() {
    setStatus("images-expected", size(expected));
    setStatus("images-loaded", size(loaded));
    setStatus("images-failed", size(failed));
    if (size(failed)) setStatus("images-failed-names", Object.keys(failed).join(" "));
  }
  function track(url) {
    if (!url || expected[url]) return;
    expected[url] = 1;
    var im = new Image();
    im.onload = function () { loaded[url] = 1; countImages(); };
    im.onerror = function () { failed[url] = 1; countImages(); };
    im.src = url;
    countImages();
  }
  function each(list, f) { Array.prototype.forEach.call(list, f); }

  // Sortable tables: click a heading; cells with data-v sort by number, empty ones last.
  function cellKey(td) {
    var v = td.getAttribute("data-v");
    if (v === null) return td.textContent;
    return v === "" ? null : parseFloat(v);
  }
  function sortable(table) {
    var ths = table.tHead.rows[0].cells;
    each(ths, function (th, col) {
      th.addEventListener("click", function () {
        var asc = !th.classList.contains("asc");
        each(ths, function (h) { h.classList.remove("asc", "desc"); });
        th.classList.add(asc ? "asc" : "desc");
        var body = table.tBodies[0], rows = Array.prototype.slice.call(body.rows);
        rows.sort(function (a, b) {
          var x = cellKey(a.cells[col]), y = cellKey(b.cells[col]);
          if (x === null || y === null) return (x === null) - (y === null);
          var c = typeof x === "number" && typeof y === "number" ? x - y
            : String(x).localeCompare(String(y), undefined, { numeric: true });
          return asc ? c : -c;
        });
        rows.forEach(function (r) { body.appendChild(r); });
      });
    });
  }

  // Rate-quality charts.
  var data = JSON.parse(document.getElementById("data").textContent);
  var COLOURS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
                 "#bcbd22", "#17becf"];
  var SVG = "http://www.w3.org/2000/svg";
  function svg(tag, attrs, parent, text) {
    var e = document.createElementNS(SVG, tag);
    for (var k in attrs) e.setAttribute(k, attrs[k]);
    if (text !== undefined) e.textContent = text;
    if (parent) parent.appendChild(e);
    return e;
  }
  function fmt(v) { return Math.abs(v) >= 1000 ? v.toFixed(0) : String(+v.toPrecision(4)); }
  function linearTicks(lo, hi) {
    var step = Math.pow(10, Math.floor(Math.log10((hi - lo) / 5)));
    if ((hi - lo) / step > 20) step *= 5; else if ((hi - lo) / step > 10) step *= 2;
    var t = [];
    for (var v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) t.push(+v.toPrecision(12));
    return t;
  }
  function logTicks(lo, hi) {  // 1-2-5 per decade, else 1..9, else linear steps within a narrow range
    var sets = [[1, 2, 5], [1, 2, 3, 4, 5, 6, 7, 8, 9]];
    for (var i = 0; i < sets.length; i++) {
      var t = [];
      for (var e = Math.floor(Math.log10(lo)); e <= Math.ceil(Math.log10(hi)); e++)
        sets[i].forEach(function (m) { var v = m * Math.pow(10, e); if (v >= lo && v <= hi) t.push(+v.toPrecision(12)); });
      if (t.length >= 3) return t;
    }
    return linearTicks(lo, hi).filter(function (v) { return v > 0; });
  }
  function drawChart(m, chart, parent) {
    var W = 420, H = 290, L = 58, R = 12, T = 26, B = 40;
    var xs = [], ys = [];
    chart.series.forEach(function (s) { s.points.forEach(function (p) { xs.push(p.x); ys.push(p.y); }); });
    var xlo = Math.min.apply(null, xs) / 1.25, xhi = Math.max.apply(null, xs) * 1.25;
    var ylo = Math.min.apply(null, ys), yhi = Math.max.apply(null, ys), pad = (yhi - ylo) * 0.08 || Math.abs(yhi) * 0.01 || 0.01;
    ylo -= pad; yhi += pad;
    var sx = function (x) { return L + (Math.log10(x) - Math.log10(xlo)) / (Math.log10(xhi) - Math.log10(xlo)) * (W - L - R); };
    var sy = function (y) { return H - B - (y - ylo) / (yhi - ylo) * (H - T - B); };
    var box = document.createElement("div");
    box.className = "chart";
    var g = svg("svg", { width: W, height: H, viewBox: "0 0 " + W + " " + H, "font-size": 10 }, box);
    svg("text", { x: L, y: 14, "font-size": 11, "font-weight": "bold" }, g, chart.scene + "; " + chart.cond);
    logTicks(xlo, xhi).forEach(function (v) {
      svg("line", { x1: sx(v), x2: sx(v), y1: T, y2: H - B, stroke: "#e4e4e4" }, g);
      svg("text", { x: sx(v), y: H - B + 13, "text-anchor": "middle" }, g, fmt(v));
    });
    linearTicks(ylo, yhi).forEach(function (v) {
      svg("line", { x1: L, x2: W - R, y1: sy(v), y2: sy(v), stroke: "#e4e4e4" }, g);
      svg("text", { x: L - 4, y: sy(v) + 3, "text-anchor": "end" }, g, fmt(v));
    });
    svg("rect", { x: L, y: T, width: W - L - R, height: H - T - B, fill: "none", stroke: "#888" }, g);
    svg("text", { x: (L + W - R) / 2, y: H - 8, "text-anchor": "middle" }, g, "Mb/s on the wire (log)");
    svg("text", { transform: "translate(12," + (T + H - B) / 2 + ") rotate(-90)", "text-anchor": "middle" }, g,
        m.metric.toUpperCase() + (m.unit ? " (" + m.unit + ")" : "") + (m.higher ? ", higher better" : ", lower better"));
    var legend = document.createElement("div");
    legend.className = "legend";
    chart.series.forEach(function (s) {
      var i = familyIndex(s.family), c = COLOURS[i % COLOURS.length], shape = Math.floor(i / COLOURS.length) % 3;
      svg("polyline", { points: s.points.map(function (p) { return sx(p.x) + "," + sy(p.y); }).join(" "), fill: "none",
                        stroke: c, "stroke-width": 1.5, "stroke-dasharray": s.anchor ? "5,3" : "none" }, g);
      s.points.forEach(function (p) {
        var x = sx(p.x), y = sy(p.y), dot = shape === 0 ? svg("circle", { cx: x, cy: y, r: 4 }, g)
          : svg("polygon", { points: shape === 1 ? [x - 4, y - 4, x + 4, y - 4, x + 4, y + 4, x - 4, y + 4].join(",")
                                                 : [x, y - 5, x + 5, y, x, y + 5, x - 5, y].join(",") }, g);
        dot.setAttribute("fill", c);
        dot.setAttribute("stroke", "#fff");
        dot.setAttribute("class", "point");
        svg("title", {}, dot, p.id + ": " + p.conf + "\nfamily: " + s.family + "\n" + fmt(p.x) + " Mb/s\n" +
            m.metric.toUpperCase() + " " + fmt(p.y) + " against the " + (p.ref === "truth" ? "ground truth" : "local reference"));
      });
      var span = document.createElement("span");
      span.innerHTML = "<b style='color:" + c + "'>" + ["&#9679;", "&#9632;", "&#9670;"][shape] + "</b> ";
      span.appendChild(document.createTextNode(s.family + (s.anchor ? " (anchor)" : "")));
      legend.appendChild(span);
    });
    box.appendChild(legend);
    parent.appendChild(box);
  }
  // One colour and marker per family across every chart (10 colours, then squares, diamonds).
  var families = [];
  function familyIndex(f) {
    if (families.indexOf(f) < 0) families.push(f);
    return families.indexOf(f);
  }
  data.charts.forEach(function (m) { m.charts.forEach(function (c) { c.series.forEach(function (s) { familyIndex(s.family); }); }); });
  var select = document.getElementById("metric"), chartsDiv = document.getElementById("charts");
  function drawCharts() {
    chartsDiv.innerHTML = "";
    var n = 0;
    data.charts.forEach(function (m) {
      if (m.metric !== select.value) return;
      m.charts.forEach(function (c) { drawChart(m, c, chartsDiv); n++; });
    });
    if (!n) chartsDiv.textContent = "No run has a bitrate and this metric.";
    setStatus("charts", n);
  }
  data.charts.forEach(function (m) {
    var o = document.createElement("option");
    o.value = o.textContent = m.metric;
    select.appendChild(o);
  });
  select.addEventListener("change", drawCharts);

  // Image viewers: one per scene, keys go to the active one.
  var viewers = [], active = null;
  function setActive(v) {
    if (active) active.root.classList.remove("active");
    active = v;
    v.root.classList.add("active");
  }
  function makeViewer(spec, parent) {
    var v = { spec: spec, i: 0, k: 1, tx: 0, ty: 0, ov: null, fitted: false };
    v.root = document.createElement("div");
    v.root.className = "viewer";
    v.root.innerHTML = "<h3></h3><div class='vbuttons'></div><div class='vinfo'></div>" +
      "<div class='viewport'><img class='main' alt='frame'><img class='overlay' alt='error map'></div>";
    v.root.querySelector("h3").textContent = spec.scene;
    v.info = v.root.querySelector(".vinfo");
    v.viewport = v.root.querySelector(".viewport");
    v.img = v.root.querySelector("img.main");
    v.overlay = v.root.querySelector("img.overlay");
    var buttons = v.root.querySelector(".vbuttons");
    spec.entries.forEach(function (e, i) {
      var b = document.createElement("button");
      b.textContent = (i < 9 ? i + 1 + " " : "") + e.name;
      b.addEventListener("click", function () { setActive(v); show(v, i); });
      buttons.appendChild(b);
      [e.src, e.error, e.flip].forEach(track);
    });
    v.img.addEventListener("load", function () { if (!v.fitted) fit(v); });
    v.root.addEventListener("mouseenter", function () { setActive(v); });
    v.viewport.addEventListener("wheel", function (ev) {
      ev.preventDefault();
      var r = v.viewport.getBoundingClientRect(), mx = ev.clientX - r.left, my = ev.clientY - r.top;
      var f = Math.exp(-ev.deltaY * 0.0015);
      v.tx = mx - (mx - v.tx) * f;
      v.ty = my - (my - v.ty) * f;
      v.k *= f;
      apply(v);
    }, { passive: false });
    var drag = null;
    v.viewport.addEventListener("pointerdown", function (ev) {
      setActive(v);
      drag = { x: ev.clientX - v.tx, y: ev.clientY - v.ty };
      try { v.viewport.setPointerCapture(ev.pointerId); } catch (err) { /* a synthetic event (self-test) */ }
      ev.preventDefault();
    });
    v.viewport.addEventListener("pointermove", function (ev) {
      if (!drag) return;
      v.tx = ev.clientX - drag.x;
      v.ty = ev.clientY - drag.y;
      apply(v);
    });
    v.viewport.addEventListener("pointerup", function () { drag = null; });
    parent.appendChild(v.root);
    show(v, 0);
    return v;
  }
  function fit(v) {
    var w = v.img.naturalWidth, h = v.img.naturalHeight, W = v.viewport.clientWidth, H = v.viewport.clientHeight;
    if (!w || !h || !W || !H) return;
    v.k = Math.min(W / w, H / h);
    v.tx = (W - w * v.k) / 2;
    v.ty = (H - h * v.k) / 2;
    v.fitted = true;
    apply(v);
  }
  function apply(v) {
    var t = "translate(" + v.tx.toFixed(1) + "px," + v.ty.toFixed(1) + "px) scale(" + v.k.toFixed(4) + ")";
    v.img.style.transform = v.overlay.style.transform = t;
  }
  function show(v, i) {
    var n = v.spec.entries.length;
    v.i = (i % n + n) % n;
    var e = v.spec.entries[v.i];
    v.img.src = e.src;
    var ov = v.ov && e[v.ov];
    if (ov) v.overlay.src = ov;
    v.viewport.classList.toggle("showov", !!ov);
    each(v.root.querySelectorAll(".vbuttons button"), function (b, j) { b.classList.toggle("on", j === v.i); });
    v.info.textContent = e.name + (e.mbps !== undefined ? " — " + fmt(e.mbps) + " Mb/s" : "") + " — " +
      (!v.ov ? "showing the frame" : ov ? "showing " + (v.ov === "error" ? "the error map" : "FLIP's map") +
       " against the " + e.against : "no " + v.ov + " map for this image (a reference)") + "; zoom " + fmt(v.k) + "x";
  }
  document.addEventListener("keydown", function (ev) {
    var v = active;
    if (!v || ev.ctrlKey || ev.metaKey || ev.altKey || /INPUT|SELECT|TEXTAREA/.test(ev.target.tagName || "")) return;
    var e = v.spec.entries[v.i];
    if (ev.key >= "1" && ev.key <= "9") show(v, Math.min(+ev.key - 1, v.spec.entries.length - 1));
    else if (ev.key === "ArrowRight" || ev.key === "ArrowDown") show(v, v.i + 1);
    else if (ev.key === "ArrowLeft" || ev.key === "ArrowUp") show(v, v.i - 1);
    else if (ev.key === "e") {
      var kinds = [null].concat(["error", "flip"].filter(function (k) { return e[k]; }));
      v.ov = kinds[(kinds.indexOf(v.ov) + 1) % kinds.length];
      show(v, v.i);
    } else if (ev.key === "0") { fit(v); show(v, v.i); }
    else return;
    ev.preventDefault();
  });

  // With #selftest: sort the runs by Mb/s, zoom the first viewer, switch it to its first run
  // by key, overlay the error map and step on; record what changed in #status.
  function selftest() {
    var notes = [], ok = true;
    var runs = document.getElementById("runs"), th = null;
    if (runs) each(runs.tHead.rows[0].cells, function (h) { if (h.textContent === "Mb/s") th = h; });
    if (th) {
      th.click();
      var col = th.cellIndex, vals = [];
      each(runs.tBodies[0].rows, function (r) { vals.push(cellKey(r.cells[col])); });
      var sorted = vals.every(function (x, j) { return j === 0 || x === null || vals[j - 1] <= x; });
      setStatus("sort-ok", sorted);
      if (!sorted) { ok = false; notes.push("runs not sorted by Mb/s: " + vals.join(",")); }
    }
    var v = viewers[0];
    if (!v) { setStatus("selftest", ok ? "pass (no viewer: no images)" : "fail: " + notes.join("; ")); return; }
    setActive(v);
    var key = function (k) { document.dispatchEvent(new KeyboardEvent("keydown", { key: k, bubbles: true, cancelable: true })); };
    var first = v.spec.entries.findIndex(function (e) { return e.error; });
    var r = v.viewport.getBoundingClientRect();
    var t0 = v.img.style.transform;
    v.viewport.dispatchEvent(new WheelEvent("wheel", { deltaY: -300, clientX: r.left + r.width / 3,
                                                       clientY: r.top + r.height / 3, bubbles: true, cancelable: true }));
    var tZoom = v.img.style.transform, px = r.left + r.width / 2, py = r.top + r.height / 2;
    [["pointerdown", 0], ["pointermove", 30], ["pointerup", 30]].forEach(function (s) {
      v.viewport.dispatchEvent(new PointerEvent(s[0], { pointerId: 1, clientX: px + s[1], clientY: py + s[1], bubbles: true }));
    });
    var before = v.img.getAttribute("src"), tBefore = v.img.style.transform;
    key(String(first + 1));
    var after = v.img.getAttribute("src"), tAfter = v.img.style.transform;
    key("e");
    var overlay = v.viewport.classList.contains("showov") ? v.overlay.getAttribute("src") : "";
    key("ArrowRight");
    var next = v.img.getAttribute("src");
    setStatus("src-before", before);
    setStatus("src-after", after);
    setStatus("src-next", next);
    setStatus("overlay-src", overlay);
    setStatus("transform-before", tBefore);
    setStatus("transform-after", tAfter);
    if (first < 1 || before === after) { ok = false; notes.push("the key did not change the image"); }
    if (tZoom === t0 || tBefore === tZoom || tBefore !== tAfter) { ok = false; notes.push("zoom or pan not applied or not kept"); }
    if (overlay !== v.spec.entries[first].error) { ok = false; notes.push("'e' did not show the error map"); }
    setStatus("selftest", ok ? "pass" : "fail: " + notes.join("; "));
    // To the top of the page, so that a headless screenshot of one window shows it (scrolling
    // gives headless Chromium's --screenshot a blank page).
    document.body.insertBefore(v.root, status.nextSibling);
  }

  each(document.querySelectorAll("table.sortable"), sortable);
  each(document.querySelectorAll("img[src]"), function (im) { track(im.getAttribute("src")); });
  drawCharts();
  var vdiv = document.getElementById("viewers");
  data.viewers.forEach(function (spec) { viewers.push(makeViewer(spec, vdiv)); });
  if (viewers.length) setActive(viewers[0]);
  else vdiv.textContent = "No per-run images in images/ (a published report keeps only the grids below).";
  setStatus("viewers", viewers.length);
  setStatus("ready", 1);
  if (location.hash === "#selftest") {
    var waited = 0;
    (function poll() {
      var settled = size(loaded) + size(failed) === size(expected) && viewers.every(function (v) { return v.fitted; });
      if (settled || waited > 4000) { if (!settled) setStatus("selftest-timeout", 1); selftest(); return; }
      waited += 50;
      setTimeout(poll, 50);
    })();
  }
})();
