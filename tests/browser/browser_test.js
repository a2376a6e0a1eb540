// report.html and the explorer page in Debian's headless Chromium, driven by
// puppeteer-core (tests/browser/package-lock.json, installed by .ci/setup).
// usage: node browser_test.js BRDFKIT SOURCE_DIR WORK_DIR
// Checks: no console error or page error; every figure renders non-blank;
// moving the theta_i slider (key presses, as a user would) plots the values
// `brdfkit eval` gives at those angles, and the hover read-out shows them.
// Writes report.png and explorer.png into WORK_DIR.
'use strict';
const {execFileSync} = require('child_process');
const fs = require('fs');
const path = require('path');
const puppeteer = require('puppeteer-core');

const [exe, sourceDir, work] = process.argv.slice(2).map((p) => p && path.resolve(p));
if (!exe || !sourceDir || !work) {
  console.error('usage: node browser_test.js BRDFKIT SOURCE_DIR WORK_DIR');
  process.exit(2);
}
fs.rmSync(work, {recursive: true, force: true});
fs.mkdirSync(work, {recursive: true});
let failures = 0;
function check(ok, what) {
  console.log((ok ? 'ok   ' : 'FAIL ') + what);
  if (!ok) ++failures;
}
function brdfkit(args) { return execFileSync(exe, args, {encoding: 'utf8'}); }

// The default scene, made small: fewer albedo nodes, the quick integrator study.
const scene = JSON.parse(fs.readFileSync(path.join(sourceDir, 'examples', 'default.json'), 'utf8'));
delete scene['$schema'];
for (const t of scene.tasks) {
  if (t.type === 'albedo') t.axes = 'mu:8,alpha:8:0.001:1';
  if (t.type === 'convergence') t.quick = true;
}
fs.writeFileSync(path.join(work, 'scene.json'), JSON.stringify(scene));
brdfkit(['run', path.join(work, 'scene.json'), '--out', path.join(work, 'out'), '--quiet']);

// Two materials overlaid: a measured-looking plastic and a rougher GGX.
const materials = [
  {model: 'lambert+ggx', params: 'lambert.albedo=0.05:0.12:0.4,ggx.alpha=0.15,ggx.f0=0.04'},
  {model: 'ggx', params: 'alpha=0.3'},
];
const explorer = path.join(work, 'explorer.html');
brdfkit(['view', ...materials.map((m) => m.model + ':' + m.params), '--out', explorer]);

function evalGreen(m, wiDeg, woDeg) {
  const out = brdfkit(['eval', '--model', m.model, '--params', m.params, '--wi-deg', wiDeg, '--wo-deg', woDeg, '--json']);
  return JSON.parse(out).f[1];
}
const relClose = (a, b, tol) => Math.abs(a - b) <= tol * Math.max(Math.abs(a), Math.abs(b), 1e-30);

async function openPage(browser, file) {
  const page = await browser.newPage();
  const errors = [];
  page.on('console', (m) => { if (m.type() === 'error') errors.push(m.text()); });
  page.on('pageerror', (e) => errors.push(String(e)));
  page.on('requestfailed', (r) => errors.push('request failed: ' + r.url()));
  await page.setViewport({width: 1200, height: 900});
  await page.goto('file://' + file, {waitUntil: 'load'});
  return {page, errors};
}

// Share of non-white pixels of every canvas under `root`.
function canvasInk(page) {
  return page.evaluate(() => Array.from(document.querySelectorAll('#brdf-explorer canvas')).map((c) => {
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let ink = 0;
    for (let i = 0; i < d.length; i += 4) if (d[i] < 235 || d[i + 1] < 235 || d[i + 2] < 235) ++ink;
    return {id: c.id, ink: ink / (c.width * c.height)};
  }));
}

(async () => {
  const browser = await puppeteer.launch({
    executablePath: process.env.BRDFKIT_CHROMIUM || '/usr/bin/chromium',
    headless: true,
    args: ['--no-sandbox', '--disable-gpu', '--disable-dev-shm-usage', '--no-first-run', '--disable-background-networking',
           '--disable-component-update', '--disable-sync'],
  });
  try {
    // --- the explorer page ------------------------------------------------------
    const {page, errors} = await openPage(browser, explorer);
    await page.waitForSelector('#brdf-explorer[data-ready="true"]', {timeout: 10000});
    for (const c of await canvasInk(page)) check(c.ink > 0.02, `explorer figure ${c.id} is drawn (${(100 * c.ink).toFixed(1)} % ink)`);
    const thetas = await page.evaluate(() => window.brdfExplorer.data.theta_i_deg);
    const start = await page.evaluate(() => window.brdfExplorer.state.ti);
    // Move the slider with the keyboard: 30 -> 50 degrees (10 steps of 2).
    await page.focus('#brdf-theta-i');
    for (let k = 0; k < 10; ++k) await page.keyboard.press('ArrowRight');
    const ti = await page.evaluate(() => window.brdfExplorer.state.ti);
    check(ti === start + 10 && thetas[ti] === 50, `slider moved to theta_i = ${thetas[ti]} deg`);
    const plotted = await page.evaluate(() => window.brdfExplorer.state.plotted);
    for (let m = 0; m < materials.length; ++m)
      for (const a of [-50, -20, 0, 35, 70]) {
        const k = plotted.in_plane[m].angle_deg.indexOf(a);
        const want = evalGreen(materials[m], `${thetas[ti]},0`, `${Math.abs(a)},${a >= 0 ? 0 : 180}`);
        check(relClose(plotted.in_plane[m].f[k], want, 1e-6),
              `in-plane ${materials[m].model} at theta_o = ${a}: plotted ${plotted.in_plane[m].f[k]}, eval ${want}`);
        const k2 = plotted.out_of_plane[m].angle_deg.indexOf(a);
        const want2 = evalGreen(materials[m], `${thetas[ti]},0`, `${Math.abs(a)},${a >= 0 ? 90 : 270}`);
        check(relClose(plotted.out_of_plane[m].f[k2], want2, 1e-6),
              `out-of-plane ${materials[m].model} at ${a}: plotted ${plotted.out_of_plane[m].f[k2]}, eval ${want2}`);
      }
    // Hover over the in-plane plot at theta_o = -40 deg: the read-out shows eval's value (4 digits).
    const box = await (await page.$('#brdf-in-plane')).boundingBox();
    const sx = box.width / 660, sy = box.height / 460, a = -40 * Math.PI / 180;
    await page.mouse.move(box.x + (330 + 150 * Math.sin(a)) * sx, box.y + (395 - 150 * Math.cos(a)) * sy);
    const tip = await page.evaluate(() => document.querySelector('#brdf-in-plane').parentNode.querySelector('.tip').textContent);
    const first = Number(/: ([0-9.e+-]+) 1\/sr/.exec(tip.split('\n')[1])[1]);
    const want = evalGreen(materials[0], '50,0', '40,180');
    check(tip.startsWith('theta_o = -40 deg') && relClose(first, want, 1e-3), `hover read-out "${tip.split('\n')[1]}" against eval ${want}`);
    await page.click('#brdf-log');
    for (const c of await canvasInk(page)) check(c.ink > 0.02, `log radius: ${c.id} is drawn`);
    await page.click('#brdf-log');
    await page.screenshot({path: path.join(work, 'explorer.png'), fullPage: true});
    check(errors.length === 0, 'explorer: no console error' + (errors.length ? ': ' + errors.join('; ') : ''));

    // --- report.html of the scene ----------------------------------------------------
    const report = await openPage(browser, path.join(work, 'out', 'report.html'));
    await report.page.waitForFunction(() => document.body.getAttribute('data-figures-rendered') !== 'pending', {timeout: 10000});
    const rendered = await report.page.evaluate(() => document.body.getAttribute('data-figures-rendered'));
    const [ok, all] = rendered.split('/').map(Number);
    check(all >= 9 && ok === all, `report: ${rendered} SVG figures rendered`);
    const blank = await report.page.evaluate(() => Array.from(document.querySelectorAll('img.plot')).filter(
      (i) => !(i.naturalWidth > 100 && i.getBoundingClientRect().height > 100)).map((i) => i.alt));
    check(blank.length === 0, 'report: every SVG figure has a size' + (blank.length ? ': ' + blank.join(', ') : ''));
    const wide = await report.page.evaluate(() => Array.from(document.querySelectorAll('table')).filter(
      (t) => t.getBoundingClientRect().right > document.documentElement.clientWidth + 1).length);
    check(wide === 0, 'report: no table runs past the right edge');
    // Every text of every SVG figure (titles, tick values, colour-bar and
    // legend labels) lies inside the figure, as the browser lays it out.
    const clipped = await report.page.evaluate(() => {
      const out = [];
      for (const img of document.querySelectorAll('img.plot')) {
        const [head, body] = img.src.split(',');
        const text = head.endsWith(';base64') ? atob(body) : decodeURIComponent(body);
        const holder = document.createElement('div');
        holder.style.cssText = 'position:absolute;left:0;top:0';
        holder.innerHTML = text;
        document.body.appendChild(holder);
        const svg = holder.querySelector('svg');
        const frame = svg.getBoundingClientRect();
        for (const t of svg.querySelectorAll('text')) {
          const b = t.getBoundingClientRect();
          if (b.width === 0) continue;
          if (b.left < frame.left - 1 || b.right > frame.right + 1 || b.top < frame.top - 1 || b.bottom > frame.bottom + 1)
            out.push(`${img.alt}: "${t.textContent}" (${b.left.toFixed(0)}..${b.right.toFixed(0)} of ${frame.width.toFixed(0)})`);
        }
        holder.remove();
      }
      return out;
    });
    check(clipped.length === 0, 'report: no figure text runs past its figure\'s edge' + (clipped.length ? ': ' + clipped.join('; ') : ''));
    await report.page.waitForSelector('#brdf-explorer[data-ready="true"]', {timeout: 10000});
    for (const c of await canvasInk(report.page)) check(c.ink > 0.02, `report explorer ${c.id} is drawn`);
    await report.page.screenshot({path: path.join(work, 'report.png'), fullPage: true});
    check(report.errors.length === 0, 'report: no console error' + (report.errors.length ? ': ' + report.errors.join('; ') : ''));
  } finally {
    await browser.close();
  }
  console.log(`screenshots: ${path.join(work, 'explorer.png')}, ${path.join(work, 'report.png')}`);
  process.exit(failures ? 1 : 0);
})().catch((e) => {
  console.error(e);
  process.exit(1);
});
