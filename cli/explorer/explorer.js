// brdfkit explorer: draws the values brdfkit precomputed (the JSON element
// #brdf-explorer-data, float32 arrays in base64) on canvases. It evaluates
// no model: every number shown is looked up in those grids.
(function () {
  'use strict';
  var root = document.getElementById('brdf-explorer');
  var D = JSON.parse(document.getElementById('brdf-explorer-data').textContent);
  var NT = D.theta_i_deg.length, NS = D.slice_deg.length, NLT = D.lobe_theta_deg.length,
      NLP = D.lobe_phi_deg.length, NH = D.halfdiff_n;
  var CH = ['red', 'green', 'blue'];

  function decode(b64) {
    var s = atob(b64), u = new Uint8Array(s.length);
    for (var i = 0; i < s.length; ++i) u[i] = s.charCodeAt(i);
    return new Float32Array(u.buffer);
  }
  D.materials.forEach(function (m) {
    ['in_plane', 'out_of_plane', 'lobe', 'albedo', 'halfdiff'].forEach(function (k) { m[k] = decode(m[k]); });
    m.visible = true;
  });

  var state = {ti: D.theta_i_deg.indexOf(30) >= 0 ? D.theta_i_deg.indexOf(30) : 0, phi: 0, ch: 1, log: false,
               image: 0, yaw: -0.6, pitch: 0.45, plotted: {}};

  // --- page structure --------------------------------------------------------
  function el(tag, attrs, parent, text) {
    var e = document.createElement(tag);
    for (var k in attrs) e.setAttribute(k, attrs[k]);
    if (text !== undefined) e.textContent = text;
    if (parent) parent.appendChild(e);
    return e;
  }
  var controls = el('div', {'class': 'controls'}, root);
  var tiLabel = el('label', {}, controls, 'theta_i ');
  var tiSlider = el('input', {type: 'range', id: 'brdf-theta-i', min: 0, max: NT - 1, step: 1, value: state.ti}, tiLabel);
  var tiOut = el('output', {}, tiLabel);
  var anisotropic = D.materials.some(function (m) { return m.phi_i_deg.length > 1; });
  var phiLabel = el('label', {}, controls, 'phi_i ');
  var phiSlider = el('input', {type: 'range', id: 'brdf-phi-i', min: 0, max: 180, step: 30, value: 0}, phiLabel);
  var phiOut = el('output', {}, phiLabel);
  if (!anisotropic) {
    phiSlider.disabled = true;
    phiLabel.title = 'every material here is isotropic: its values do not change with phi_i';
  }
  var chLabel = el('label', {}, controls, 'channel ');
  var chSelect = el('select', {id: 'brdf-channel'}, chLabel);
  CH.forEach(function (c, i) { var o = el('option', {value: i}, chSelect, c); if (i === state.ch) o.selected = true; });
  var logLabel = el('label', {}, controls);
  var logBox = el('input', {type: 'checkbox', id: 'brdf-log'}, logLabel);
  logLabel.appendChild(document.createTextNode(' log radius (3 decades)'));
  var mats = el('div', {'class': 'materials'}, controls);
  D.materials.forEach(function (m, k) {
    var l = el('label', {title: m.description}, mats);
    var b = el('input', {type: 'checkbox', 'data-material': k}, l);
    b.checked = true;
    b.addEventListener('change', function () { m.visible = b.checked; draw(); });
    el('span', {'class': 'swatch', style: 'background:' + m.colour}, l);
    l.appendChild(document.createTextNode(m.label));
  });

  var grid = el('div', {'class': 'grid'}, root);
  function figure(id, caption) {
    var f = el('figure', {}, grid);
    var c = el('canvas', {id: id, width: 660, height: 460}, f);
    el('figcaption', {}, f, caption);
    var tip = el('div', {'class': 'tip'}, f);
    return {canvas: c, ctx: c.getContext('2d'), tip: tip, fig: f};
  }
  var F = {
    in_plane: figure('brdf-in-plane', 'f_r [1/sr] in the plane of incidence; light from the positive side (arrow), ' +
                     'mirror direction at the negative angle.'),
    out_of_plane: figure('brdf-out-of-plane', 'f_r [1/sr] in the plane through the normal perpendicular to the plane ' +
                         'of incidence.'),
    lobe: figure('brdf-lobe', '3D lobe: f_r [1/sr] as the distance from the origin over the upper hemisphere ' +
                 '(normal up; drag to turn). Dark line: towards the light.'),
    halfdiff: figure('brdf-halfdiff', 'theta_h x theta_d image at phi_d = 90 deg, log colour scale; grey: below the ' +
                     'horizon or no value.'),
    albedo: figure('brdf-albedo', 'Directional albedo E(wo) = int f_r cos(theta_i) dwi at wo = (theta, phi_i); ' +
                   'the dashed line marks the slider.')
  };
  var imgLabel = el('label', {}, F.halfdiff.fig, 'material ');
  imgLabel.style.fontSize = '12px';
  var imgSelect = el('select', {id: 'brdf-image-material'}, imgLabel);
  D.materials.forEach(function (m, k) { el('option', {value: k}, imgSelect, m.label); });

  // --- lookups ---------------------------------------------------------------
  function phiIndex(m) { return m.phi_i_deg.length === 1 ? 0 : Math.round(state.phi / 30); }
  function slice(m, kind) {
    var base = ((phiIndex(m) * NT + state.ti) * NS) * 3, out = new Array(NS);
    for (var s = 0; s < NS; ++s) out[s] = m[kind][base + 3 * s + state.ch];
    return out;
  }
  function fmt(v) { return isFinite(v) ? (Math.abs(v) >= 1e4 || (Math.abs(v) < 1e-3 && v !== 0) ? v.toExponential(3) : v.toPrecision(4)) : 'none'; }
  function visible() { return D.materials.filter(function (m) { return m.visible; }); }

  // --- drawing helpers -------------------------------------------------------
  function clear(f, title) {
    var c = f.ctx;
    c.setTransform(1, 0, 0, 1, 0, 0);
    c.fillStyle = '#fff';
    c.fillRect(0, 0, f.canvas.width, f.canvas.height);
    c.fillStyle = '#222';
    c.font = 'bold 17px sans-serif';
    c.textAlign = 'left';
    c.textBaseline = 'top';
    c.fillText(title, 10, 8);
    c.font = '14px sans-serif';
    return c;
  }
  function niceTicks(lo, hi, n) {
    var step = Math.pow(10, Math.floor(Math.log10((hi - lo) / n))), t = [];
    [1, 2, 5, 10].some(function (k) { if ((hi - lo) / (k * step) <= n) { step *= k; return true; } return false; });
    for (var v = Math.ceil(lo / step) * step; v <= hi + 1e-9 * step; v += step) t.push(Math.abs(v) < 1e-12 * step ? 0 : v);
    return t;
  }
  var VIRIDIS = [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]];
  function viridis(t) {
    t = Math.min(1, Math.max(0, t)) * 4;
    var i = Math.min(3, Math.floor(t)), a = VIRIDIS[i], b = VIRIDIS[i + 1], u = t - i;
    return 'rgb(' + [0, 1, 2].map(function (k) { return Math.round(a[k] + (b[k] - a[k]) * u); }).join(',') + ')';
  }
  function showTip(f, ev, text) {
    var r = f.fig.getBoundingClientRect();
    f.tip.textContent = text;
    f.tip.style.display = 'block';
    f.tip.style.left = Math.min(ev.clientX - r.left + 12, r.width - 160) + 'px';
    f.tip.style.top = (ev.clientY - r.top + 12) + 'px';
  }
  function canvasPoint(f, ev) {
    var r = f.canvas.getBoundingClientRect();
    return [(ev.clientX - r.left) * f.canvas.width / r.width, (ev.clientY - r.top) * f.canvas.height / r.height];
  }

  // --- polar slices ----------------------------------------------------------
  var P = {cx: 330, cy: 395, R: 300};
  function radiusOf(v, scale) {
    if (!(v > 0)) return 0;
    return scale.log ? Math.max(0, Math.log10(v / scale.floor)) / 3 : v / scale.max;
  }
  function drawPolar(kind, title) {
    var f = F[kind], c = clear(f, title + ', ' + CH[state.ch] + ', theta_i = ' + D.theta_i_deg[state.ti] + ' deg');
    var series = visible().map(function (m) { return {m: m, f: slice(m, kind)}; });
    var vmax = 0;
    series.forEach(function (s) { s.f.forEach(function (v) { if (v > vmax) vmax = v; }); });
    if (!(vmax > 0)) vmax = 1;
    var scale = {log: state.log, max: vmax, floor: Math.pow(10, Math.ceil(Math.log10(vmax)) - 3)};
    if (!state.log) {
      var t = niceTicks(0, vmax, 4);
      scale.max = t[t.length - 1] < vmax ? t[t.length - 1] + (t[1] - t[0]) : t[t.length - 1];
      scale.rings = t.filter(function (v) { return v > 0; });
    } else {
      scale.rings = [1, 2, 3].map(function (k) { return scale.floor * Math.pow(10, k); });
    }
    c.strokeStyle = '#ccc';
    c.lineWidth = 1;
    c.fillStyle = '#555';
    c.textAlign = 'center';
    c.textBaseline = 'top';
    scale.rings.forEach(function (v) {
      var r = radiusOf(v, scale) * P.R;
      c.beginPath(); c.arc(P.cx, P.cy, r, Math.PI, 2 * Math.PI); c.stroke();
      c.fillText(fmt(v), P.cx + r, P.cy + 4);
    });
    for (var deg = -90; deg <= 90; deg += 15) {
      var a = deg * Math.PI / 180;
      c.beginPath(); c.moveTo(P.cx, P.cy); c.lineTo(P.cx + P.R * Math.sin(a), P.cy - P.R * Math.cos(a)); c.stroke();
      if (deg % 30 === 0) {
        c.textBaseline = 'bottom';
        c.fillText(deg + '\u00b0', P.cx + 1.06 * P.R * Math.sin(a), P.cy - 1.04 * P.R * Math.cos(a) + (Math.abs(deg) === 90 ? 8 : 0));
      }
    }
    c.textBaseline = 'top';
    c.fillText('f_r [1/sr]' + (state.log ? ', log radius' : '') + '; angle of wo from the normal', P.cx, P.cy + 24);
    if (kind === 'in_plane') {  // the direction of the light
      var ai = D.theta_i_deg[state.ti] * Math.PI / 180;
      c.strokeStyle = '#333'; c.lineWidth = 2;
      c.beginPath(); c.moveTo(P.cx + 1.0 * P.R * Math.sin(ai), P.cy - 1.0 * P.R * Math.cos(ai));
      c.lineTo(P.cx + 0.88 * P.R * Math.sin(ai), P.cy - 0.88 * P.R * Math.cos(ai)); c.stroke();
      c.fillStyle = '#333'; c.fillText('light', P.cx + 0.84 * P.R * Math.sin(ai), P.cy - 0.84 * P.R * Math.cos(ai));
    }
    c.lineWidth = 2;
    series.forEach(function (s) {
      c.strokeStyle = s.m.colour;
      c.beginPath();
      var pen = false;
      for (var k = 0; k < NS; ++k) {
        var v = s.f[k];
        if (!isFinite(v)) { pen = false; continue; }
        var a = D.slice_deg[k] * Math.PI / 180, r = Math.min(1.02, radiusOf(v, scale)) * P.R;
        var x = P.cx + r * Math.sin(a), y = P.cy - r * Math.cos(a);
        if (pen) c.lineTo(x, y); else c.moveTo(x, y);
        pen = true;
      }
      c.stroke();
    });
    state.plotted[kind] = series.map(function (s) {
      return {label: s.m.label, angle_deg: D.slice_deg.slice(), f: s.f.slice()};
    });
  }
  function polarHover(kind) {
    var f = F[kind];
    f.canvas.addEventListener('mousemove', function (ev) {
      var p = canvasPoint(f, ev), a = Math.atan2(p[0] - P.cx, P.cy - p[1]) * 180 / Math.PI;
      var k = Math.round(a - D.slice_deg[0]);
      if (k < 0 || k >= NS) { f.tip.style.display = 'none'; return; }
      var lines = ['theta_o = ' + D.slice_deg[k] + ' deg (theta_i = ' + D.theta_i_deg[state.ti] + ')'];
      visible().forEach(function (m) { lines.push(m.label + ': ' + fmt(slice(m, kind)[k]) + ' 1/sr'); });
      showTip(f, ev, lines.join('\n'));
    });
    f.canvas.addEventListener('mouseleave', function () { f.tip.style.display = 'none'; });
  }

  // --- 3D lobe ---------------------------------------------------------------
  function drawLobe() {
    var f = F.lobe, c = clear(f, '3D lobe, ' + CH[state.ch] + ', theta_i = ' + D.theta_i_deg[state.ti] + ' deg');
    var cy = Math.cos(state.yaw), sy = Math.sin(state.yaw), cp = Math.cos(state.pitch), sp = Math.sin(state.pitch);
    var S = 250, ox = 330, oy = 360;
    function project(x, y, z) {
      var xr = x * cy - y * sy, yr = x * sy + y * cy;
      return [ox + S * xr, oy - S * (z * cp - yr * sp)];
    }
    var vmax = 0, ms = visible();
    var lobes = ms.map(function (m) {
      var base = ((phiIndex(m) * NT + state.ti) * NLT * NLP) * 3, v = new Array(NLT * NLP);
      for (var q = 0; q < NLT * NLP; ++q) { v[q] = m.lobe[base + 3 * q + state.ch]; if (v[q] > vmax) vmax = v[q]; }
      return {m: m, v: v};
    });
    if (!(vmax > 0)) vmax = 1;
    // Horizon circle and axes.
    c.strokeStyle = '#bbb'; c.lineWidth = 1;
    c.beginPath();
    for (var k = 0; k <= 72; ++k) {
      var ph = k * Math.PI / 36, p = project(Math.cos(ph), Math.sin(ph), 0);
      if (k) c.lineTo(p[0], p[1]); else c.moveTo(p[0], p[1]);
    }
    c.stroke();
    [[1, 0, 0, 'x'], [0, 1, 0, 'y'], [0, 0, 1, 'n']].forEach(function (a) {
      var p0 = project(0, 0, 0), p1 = project(a[0], a[1], a[2]);
      c.beginPath(); c.moveTo(p0[0], p0[1]); c.lineTo(p1[0], p1[1]); c.stroke();
      c.fillStyle = '#777'; c.fillText(a[3], p1[0] + 3, p1[1] - 14);
    });
    var ti = D.theta_i_deg[state.ti] * Math.PI / 180, pi = state.phi * Math.PI / 180;
    var l0 = project(0, 0, 0), l1 = project(Math.sin(ti) * Math.cos(pi), Math.sin(ti) * Math.sin(pi), Math.cos(ti));
    c.strokeStyle = '#333'; c.lineWidth = 2;
    c.beginPath(); c.moveTo(l0[0], l0[1]); c.lineTo(l1[0], l1[1]); c.stroke();
    c.lineWidth = 1.2;
    lobes.forEach(function (L) {
      c.strokeStyle = L.m.colour;
      function pt(i, j) {
        var th = D.lobe_theta_deg[i] * Math.PI / 180, ph = D.lobe_phi_deg[j] * Math.PI / 180;
        var r = L.v[i * NLP + j] / vmax;
        if (!isFinite(r)) r = 0;
        return project(r * Math.sin(th) * Math.cos(ph), r * Math.sin(th) * Math.sin(ph), r * Math.cos(th));
      }
      for (var i = 0; i < NLT; ++i) {
        c.beginPath();
        for (var j = 0; j < NLP; ++j) { var p = pt(i, j); if (j) c.lineTo(p[0], p[1]); else c.moveTo(p[0], p[1]); }
        c.stroke();
      }
      for (var j = 0; j < NLP - 1; j += 1) {
        c.beginPath();
        for (var i = 0; i < NLT; ++i) { var p = pt(i, j); if (i) c.lineTo(p[0], p[1]); else c.moveTo(p[0], p[1]); }
        c.stroke();
      }
    });
    c.fillStyle = '#555';
    c.fillText('unit length = ' + fmt(vmax) + ' 1/sr', 10, 32);
    state.plotted.lobe = lobes.map(function (L) { return {label: L.m.label, max: Math.max.apply(null, L.v.filter(isFinite))}; });
  }
  (function lobeDrag() {
    var f = F.lobe, last = null;
    f.canvas.addEventListener('mousedown', function (ev) { last = [ev.clientX, ev.clientY]; });
    window.addEventListener('mouseup', function () { last = null; });
    f.canvas.addEventListener('mousemove', function (ev) {
      if (!last) return;
      state.yaw += (ev.clientX - last[0]) * 0.01;
      state.pitch = Math.max(-0.2, Math.min(1.5, state.pitch + (ev.clientY - last[1]) * 0.01));
      last = [ev.clientX, ev.clientY];
      drawLobe();
    });
  })();

  // --- theta_h x theta_d image ----------------------------------------------
  var I = {x0: 70, y0: 50, w: 440, h: 360};
  function edges(centres) {
    var e = [0];
    for (var i = 0; i + 1 < centres.length; ++i) e.push(0.5 * (centres[i] + centres[i + 1]));
    e.push(90);
    return e;
  }
  var HX = edges(D.halfdiff_theta_h_deg), HY = edges(D.halfdiff_theta_d_deg);
  function drawImage() {
    var m = D.materials[state.image];
    var f = F.halfdiff, c = clear(f, 'theta_h x theta_d, ' + m.label + ', ' + CH[state.ch]);
    var lo = Infinity, hi = -Infinity, n = NH * NH, lv = new Float64Array(n);
    for (var q = 0; q < n; ++q) {
      var v = m.halfdiff[3 * q + state.ch];
      lv[q] = v > 0 ? Math.log10(v) : NaN;
      if (lv[q] < lo) lo = lv[q];
      if (lv[q] > hi) hi = lv[q];
    }
    if (!(hi > lo)) { lo = (isFinite(lo) ? lo : 0) - 0.5; hi = lo + 1; }
    lo = Math.max(lo, hi - 6);  // at most six decades; lower values saturate
    function X(deg) { return I.x0 + I.w * deg / 90; }
    function Y(deg) { return I.y0 + I.h * (1 - deg / 90); }
    c.fillStyle = '#b9b9b9';
    c.fillRect(I.x0, I.y0, I.w, I.h);
    for (var j = 0; j < NH; ++j)
      for (var i = 0; i < NH; ++i) {
        var z = lv[j * NH + i];
        if (!isFinite(z)) continue;
        c.fillStyle = viridis((z - lo) / (hi - lo));
        c.fillRect(X(HX[i]), Y(HY[j + 1]), X(HX[i + 1]) - X(HX[i]) + 0.6, Y(HY[j]) - Y(HY[j + 1]) + 0.6);
      }
    c.strokeStyle = '#222'; c.strokeRect(I.x0, I.y0, I.w, I.h);
    c.fillStyle = '#222';
    c.textAlign = 'center'; c.textBaseline = 'top';
    [0, 15, 30, 45, 60, 75, 90].forEach(function (d) {
      c.fillText(d, X(d), I.y0 + I.h + 4);
      c.textAlign = 'right'; c.textBaseline = 'middle'; c.fillText(d, I.x0 - 5, Y(d));
      c.textAlign = 'center'; c.textBaseline = 'top';
    });
    c.fillText('theta_h [deg]', I.x0 + I.w / 2, I.y0 + I.h + 22);
    c.save(); c.translate(22, I.y0 + I.h / 2); c.rotate(-Math.PI / 2); c.fillText('theta_d [deg]', 0, -8); c.restore();
    // Colour bar in powers of ten.
    var bx = I.x0 + I.w + 20, bw = 18;
    for (var k = 0; k < 100; ++k) {
      c.fillStyle = viridis((k + 0.5) / 100);
      c.fillRect(bx, I.y0 + I.h * (1 - (k + 1) / 100), bw, I.h / 100 + 0.6);
    }
    c.strokeStyle = '#222'; c.strokeRect(bx, I.y0, bw, I.h);
    c.fillStyle = '#222'; c.textAlign = 'left'; c.textBaseline = 'middle';
    var step = hi - lo > 3 ? 1 : hi - lo > 1 ? 0.5 : 0.25;
    for (var e = Math.ceil(lo / step) * step; e <= hi + 1e-9; e += step)
      c.fillText(fmt(Math.pow(10, e)), bx + bw + 4, I.y0 + I.h * (1 - (e - lo) / (hi - lo)));
    c.save(); c.translate(bx + bw + 70, I.y0 + I.h / 2); c.rotate(-Math.PI / 2); c.textAlign = 'center';
    c.fillText('f_r [1/sr]', 0, 0); c.restore();
    state.plotted.halfdiff = {label: m.label, log10_min: lo, log10_max: hi};
  }
  (function imageHover() {
    var f = F.halfdiff;
    function find(edgesArr, d) { for (var i = 0; i + 1 < edgesArr.length; ++i) if (d < edgesArr[i + 1]) return i; return -1; }
    f.canvas.addEventListener('mousemove', function (ev) {
      var p = canvasPoint(f, ev), th = (p[0] - I.x0) / I.w * 90, td = (1 - (p[1] - I.y0) / I.h) * 90;
      if (th < 0 || th > 90 || td < 0 || td > 90) { f.tip.style.display = 'none'; return; }
      var i = find(HX, th), j = find(HY, td), lines = ['theta_h = ' + D.halfdiff_theta_h_deg[i].toFixed(2) +
                  ', theta_d = ' + D.halfdiff_theta_d_deg[j].toFixed(2) + ' deg'];
      visible().forEach(function (m) { lines.push(m.label + ': ' + fmt(m.halfdiff[3 * (j * NH + i) + state.ch]) + ' 1/sr'); });
      showTip(f, ev, lines.join('\n'));
    });
    f.canvas.addEventListener('mouseleave', function () { f.tip.style.display = 'none'; });
  })();

  // --- directional albedo ------------------------------------------------------
  var A = {x0: 80, y0: 50, w: 540, h: 340};
  function albedoCurve(m) {
    var base = phiIndex(m) * NT * 3, out = new Array(NT);
    for (var k = 0; k < NT; ++k) out[k] = m.albedo[base + 3 * k + state.ch];
    return out;
  }
  function drawAlbedo() {
    var f = F.albedo, c = clear(f, 'directional albedo E, ' + CH[state.ch]);
    var series = visible().map(function (m) { return {m: m, e: albedoCurve(m)}; });
    var ymax = 0;
    series.forEach(function (s) { s.e.forEach(function (v) { if (v > ymax) ymax = v; }); });
    var ticks = niceTicks(0, Math.max(ymax * 1.05, 0.1), 5);
    var top = ticks[ticks.length - 1] < ymax ? ticks[ticks.length - 1] + (ticks[1] - ticks[0]) : ticks[ticks.length - 1];
    function X(d) { return A.x0 + A.w * d / 90; }
    function Y(v) { return A.y0 + A.h * (1 - v / top); }
    c.strokeStyle = '#ddd'; c.fillStyle = '#222'; c.lineWidth = 1;
    c.textAlign = 'right'; c.textBaseline = 'middle';
    ticks.forEach(function (v) { c.beginPath(); c.moveTo(A.x0, Y(v)); c.lineTo(A.x0 + A.w, Y(v)); c.stroke(); c.fillText(fmt(v), A.x0 - 6, Y(v)); });
    c.textAlign = 'center'; c.textBaseline = 'top';
    [0, 15, 30, 45, 60, 75, 90].forEach(function (d) {
      c.beginPath(); c.moveTo(X(d), A.y0); c.lineTo(X(d), A.y0 + A.h); c.stroke(); c.fillText(d, X(d), A.y0 + A.h + 4);
    });
    c.strokeStyle = '#222'; c.strokeRect(A.x0, A.y0, A.w, A.h);
    c.fillText('theta_o [deg]', A.x0 + A.w / 2, A.y0 + A.h + 22);
    c.save(); c.translate(20, A.y0 + A.h / 2); c.rotate(-Math.PI / 2); c.fillText('E', 0, 0); c.restore();
    c.setLineDash([5, 4]); c.strokeStyle = '#333';
    c.beginPath(); c.moveTo(X(D.theta_i_deg[state.ti]), A.y0); c.lineTo(X(D.theta_i_deg[state.ti]), A.y0 + A.h); c.stroke();
    c.setLineDash([]); c.lineWidth = 2;
    series.forEach(function (s) {
      c.strokeStyle = s.m.colour; c.beginPath();
      s.e.forEach(function (v, k) { var x = X(D.theta_i_deg[k]), y = Y(v); if (k) c.lineTo(x, y); else c.moveTo(x, y); });
      c.stroke();
    });
    state.plotted.albedo = series.map(function (s) { return {label: s.m.label, theta_deg: D.theta_i_deg.slice(), E: s.e.slice()}; });
  }
  (function albedoHover() {
    var f = F.albedo;
    f.canvas.addEventListener('mousemove', function (ev) {
      var p = canvasPoint(f, ev), d = (p[0] - A.x0) / A.w * 90, k = Math.round(d / 2);
      if (k < 0 || k >= NT) { f.tip.style.display = 'none'; return; }
      var lines = ['theta_o = ' + D.theta_i_deg[k] + ' deg'];
      visible().forEach(function (m) { lines.push(m.label + ': E = ' + fmt(albedoCurve(m)[k])); });
      showTip(f, ev, lines.join('\n'));
    });
    f.canvas.addEventListener('mouseleave', function () { f.tip.style.display = 'none'; });
  })();

  // --- wiring ----------------------------------------------------------------
  function draw() {
    tiOut.textContent = ' ' + D.theta_i_deg[state.ti] + '\u00b0';
    phiOut.textContent = ' ' + state.phi + '\u00b0';
    drawPolar('in_plane', 'in-plane');
    drawPolar('out_of_plane', 'out-of-plane');
    drawLobe();
    drawImage();
    drawAlbedo();
  }
  tiSlider.addEventListener('input', function () { state.ti = +tiSlider.value; draw(); });
  phiSlider.addEventListener('input', function () { state.phi = +phiSlider.value; draw(); });
  chSelect.addEventListener('change', function () { state.ch = +chSelect.value; draw(); });
  logBox.addEventListener('change', function () { state.log = logBox.checked; draw(); });
  imgSelect.addEventListener('change', function () { state.image = +imgSelect.value; draw(); });
  polarHover('in_plane');
  polarHover('out_of_plane');
  draw();
  // For tests and for reading values from the console.
  window.brdfExplorer = {data: D, state: state, draw: draw};
  root.setAttribute('data-ready', 'true');
})();
