// Browser tests of the calibration page: headless Debian Chromium driven by
// playwright-core, against the built page served on localhost. The
// reference for every number is `magcal` itself, run on the same input.
//
// Environment (set by `cargo xtask web-test`): WEB_ROOT (the built page),
// MAGCAL (the CLI binary), REAL_DATA (../shared/data/real), CHROMIUM
// (/usr/bin/chromium), SCREENSHOTS (a folder for the screenshots).

import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import { execFileSync, spawnSync } from 'node:child_process';
import { mkdirSync, mkdtempSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { chromium } from 'playwright-core';
import { fileURLToPath } from 'node:url';
import { serve } from '../serve.mjs';

const env = (name) => {
  const value = process.env[name];
  if (!value) throw new Error(`${name} is not set: run the tests with 'cargo xtask web-test'`);
  return value;
};
const WEB_ROOT = env('WEB_ROOT');
const MAGCAL = env('MAGCAL');
const REAL = env('REAL_DATA');
const SHOTS = env('SCREENSHOTS');
mkdirSync(SHOTS, { recursive: true });
const scratch = mkdtempSync(join(tmpdir(), 'mag-cal-web-'));
// The repository, for the snippets' checks.
const ROOT = fileURLToPath(new URL('../..', import.meta.url));
const HEADER_DIR = join(ROOT, 'mag-cal-ffi', 'include');

// `cargo check` of the Rust snippet and a `caller` of its `calibration()`
// in a crate of its own that depends on this repository's mag-cal-core (offline: the workspace's lock file and
// toolchain, its dependencies already fetched).
function checkRustSnippet(snippet, caller = 'pub fn unit() -> Result<[f32; 3], Error> {\n    Ok(calibration()?.apply([1i16, 2, 3]))\n}\n') {
  const dir = join(scratch, 'snippet-rs');
  mkdirSync(join(dir, 'src'), { recursive: true });
  writeFileSync(
    join(dir, 'Cargo.toml'),
    `[package]\nname = "snippet"\nversion = "0.0.0"\nedition = "2021"\n\n` +
      `[dependencies]\nmag-cal-core = { path = ${JSON.stringify(join(ROOT, 'mag-cal-core'))} }\n\n[workspace]\n`,
  );
  writeFileSync(join(dir, 'Cargo.lock'), readFileSync(join(ROOT, 'Cargo.lock')));
  writeFileSync(join(dir, 'rust-toolchain.toml'), readFileSync(join(ROOT, 'rust-toolchain.toml')));
  writeFileSync(
    join(dir, 'src', 'lib.rs'),
    `#![deny(warnings)]\n${snippet}\n${caller}`,
  );
  const env = { ...process.env, CARGO_TARGET_DIR: join(ROOT, 'target', 'snippet-check') };
  const run = spawnSync('cargo', ['check', '--offline', '--quiet'], { cwd: dir, env, encoding: 'utf8' });
  assert.equal(run.status, 0, `the Rust snippet does not build:\n${run.stderr}`);
}

let server;
let browser;
let url;

before(async () => {
  server = await serve(WEB_ROOT, 0);
  url = `http://127.0.0.1:${server.address().port}/`;
  browser = await chromium.launch({
    executablePath: env('CHROMIUM'),
    headless: true,
    // As root in CI: no sandbox. No background connections (the machine's
    // network is closed). WebGL through SwiftShader, as there is no GPU.
    args: [
      '--no-sandbox',
      '--disable-quic',
      '--no-first-run',
      '--disable-background-networking',
      '--disable-component-update',
      '--disable-sync',
      '--use-angle=swiftshader',
      '--enable-unsafe-swiftshader',
    ],
  });
});

after(async () => {
  await browser?.close();
  server?.close();
  rmSync(scratch, { recursive: true, force: true });
});

// A page with the core loaded; console errors fail the test.
async function openPage(init) {
  const context = await browser.newContext({ viewport: { width: 1280, height: 1500 }, acceptDownloads: true });
  const page = await context.newPage();
  const errors = [];
  page.on('pageerror', (err) => errors.push(err.message));
  page.on('console', (msg) => msg.type() === 'error' && errors.push(msg.text()));
  if (init) await page.addInitScript(init);
  await page.goto(url);
  await page.waitForFunction(() => window.magcal?.ready === true);
  return { page, errors, context };
}

// `magcal fit --format json` of a file: [exit code, parsed JSON or the
// stderr line].
function magcal(file, ...args) {
  const run = spawnSync(MAGCAL, ['fit', file, '--format', 'json', ...args], { encoding: 'utf8' });
  if (run.status === 0) return [0, JSON.parse(run.stdout)];
  return [run.status, run.stderr.trim()];
}

// The figures the page shows, at full precision (their data-value).
async function shown(page) {
  return page.evaluate(() => {
    const v = (name) => Number(document.querySelector(`[data-name="${name}"]`).dataset.value);
    return {
      hard_iron: [0, 1, 2].map((i) => v(`b${i}`)),
      soft_iron: [0, 1, 2].map((r) => [0, 1, 2].map((c) => v(`W${r}${c}`))),
      field_strength: v('field strength'),
      radial_rms: v('radial RMS'),
      fit_error: v('fit error'),
      coverage: v('coverage'),
    };
  });
}

function assertClose(actual, expected, tol, what) {
  const scale = Math.max(1, Math.abs(expected));
  assert.ok(Math.abs(actual - expected) <= tol * scale, `${what}: page ${actual}, magcal ${expected}`);
}

function assertSameCalibration(page, cli, tol) {
  for (let i = 0; i < 3; i += 1) {
    assertClose(page.hard_iron[i], cli.hard_iron[i], tol, `b[${i}]`);
    for (let j = 0; j < 3; j += 1) {
      // W is about 1 / field: compared relative to the matrix's scale.
      const scale = Math.abs(cli.soft_iron[0][0]);
      assert.ok(
        Math.abs(page.soft_iron[i][j] - cli.soft_iron[i][j]) <= tol * scale,
        `W[${i}][${j}]: page ${page.soft_iron[i][j]}, magcal ${cli.soft_iron[i][j]}`,
      );
    }
  }
  assertClose(page.field_strength, cli.field_strength, tol, 'field strength');
  assertClose(page.radial_rms, cli.quality.radial_rms, tol, 'radial RMS');
  assertClose(page.fit_error, cli.quality.fit_error, tol, 'fit error');
  assertClose(page.coverage, cli.quality.coverage, tol, 'coverage');
}

async function openFile(page, file) {
  await page.setInputFiles('#file', file);
  await page.waitForFunction((name) => document.querySelector('#verdict')?.textContent.endsWith(name), file.split('/').pop());
}

test('a shared recording shows what magcal fit gives, in f64 and f32', async () => {
  const { page, errors, context } = await openPage();
  // A MotionCal log, as a user saves a board's serial output.
  writeFileSync(join(scratch, 'motioncal_log.txt'), rawStream(streamRows().filter((_, i) => i % 6 === 0)));
  // A shared recording with lines a logger garbled (one with markup in it).
  const rows = readFileSync(join(REAL, 'icm20948_mag_300.csv'), 'utf8').split('\n');
  rows.splice(200, 0, '-12,13');
  rows.splice(100, 0, '-12,<b>x</b>,40');
  writeFileSync(join(scratch, 'icm20948_garbled.csv'), rows.join('\n'));
  for (const [name, precision, tol] of [
    ['icm20948_mag_300.csv', 'f64', 1e-9],
    ['imu_gnss_1252.csv', 'f64', 1e-9],
    ['mag3_raw_541.csv', 'f32', 1e-5],
    ['motioncal_log.txt', 'f64', 1e-9],
    ['icm20948_garbled.csv', 'f64', 1e-9],
  ]) {
    const file = join(name.startsWith('motioncal') || name.includes('garbled') ? scratch : REAL, name);
    await page.selectOption('#precision', precision);
    await openFile(page, file);
    assert.match(await page.textContent('#verdict'), /^Calibrated/);
    const [code, cli] = magcal(file, '--precision', precision);
    assert.equal(code, 0);
    assertSameCalibration(await shown(page), cli, tol);
    // The counts, as the CLI gives them.
    const samples = await page.textContent('[data-name="samples"]');
    assert.ok(samples.startsWith(`${cli.samples_used} used of`), samples);
    const columns = await page.textContent('[data-name="columns"]');
    const expected = {
      'imu_gnss_1252.csv': 'magx,magy,magz (from the header)',
      'motioncal_log.txt': execFileSync(MAGCAL, ['fit', file], { encoding: 'utf8' }).match(/columns +(.*)\n/)[1],
    };
    assert.equal(columns, expected[name] ?? 'the first three fields');
    // The lines that were no samples, as the CLI names them, as text.
    const input = execFileSync(MAGCAL, ['fit', file], { encoding: 'utf8' }).match(/\n {2}input +(.*)\n/);
    assert.equal(await page.locator('[data-name="input"]').count(), input ? 1 : 0);
    if (input) {
      assert.equal(await page.textContent('[data-name="input"]'), input[1]);
      assert.equal(await page.locator('#figures b').count(), 0);
    }

    // The warnings in the words of magcal's text report.
    const report = execFileSync(MAGCAL, ['fit', file, '--precision', precision], { encoding: 'utf8', stdio: 'pipe' });
    // (A sentence ends at '.' before the next warning or the end: its figures have decimal points.)
    const sentences = [...(await page.textContent('#message')).matchAll(/Warning: (.+?)\.(?= Warning: |$)/g)].map((m) => m[1]);
    assert.equal(sentences.length, cli.quality.warnings.length, await page.textContent('#message'));
    cli.quality.warnings.forEach((name, i) => assert.ok(report.includes(`${name}: ${sentences[i]}\n`), `${name}: ${sentences[i]}`));

    // The download is the CLI's JSON (but for the fit's time).
    const [download] = await Promise.all([page.waitForEvent('download'), page.click('#download')]);
    const saved = JSON.parse(readFileSync(await download.path(), 'utf8'));
    delete saved.timing_us;
    delete cli.timing_us;
    assert.deepEqual(saved, cli);
    // ... and `magcal apply` reads it.
    const calFile = join(scratch, `${name}.json`);
    writeFileSync(calFile, JSON.stringify(saved));
    execFileSync(MAGCAL, ['apply', calFile, file], { encoding: 'utf8', stdio: 'pipe' });

    // The C snippet compiles against the C API's header and calls it.
    const snippet = await page.evaluate(() => window.magcal.result.snippets.c);
    const cFile = join(scratch, 'snippet.c');
    writeFileSync(cFile, `${snippet}\nint main(void) {\n    float raw[3] = { 1, 2, 3 }, out[3];\n    return (int)magcal_apply(&mag_calibration, raw, out);\n}\n`);
    execFileSync('gcc', ['-std=c99', '-Wall', '-Wextra', '-Werror', '-fsyntax-only', '-I', HEADER_DIR, cFile], { stdio: 'pipe' });
    // Its numbers are the fit's, to the last digit.
    for (const v of [...cli.hard_iron, ...cli.soft_iron.flat(), cli.field_strength]) {
      assert.ok(snippet.includes(String(v)) || snippet.includes(v.toExponential()), `${v} in the C snippet`);
    }

    if (name === 'icm20948_mag_300.csv') {
      checkRustSnippet(await page.evaluate(() => window.magcal.result.snippets.rust));
    }

    // The norm plot has a dot per finite sample.
    const dots = await page.locator('#norms circle').count();
    assert.equal(dots, (await page.evaluate(() => window.magcal.result.norms.filter(Number.isFinite).length)));
    await page.screenshot({ path: join(SHOTS, `file-${name}.png`), fullPage: true });
  }
  assert.deepEqual(errors, []);
  await context.close();
});

// `magcal planar --format json` of a file: [exit code, parsed JSON or the
// stderr line].
function magcalPlanar(file, ...args) {
  const run = spawnSync(MAGCAL, ['planar', file, '--format', 'json', ...args], { encoding: 'utf8' });
  if (run.status === 0) return [0, JSON.parse(run.stdout)];
  return [run.status, run.stderr.trim()];
}

// A file dropped on the page, as a user drags it from a file manager.
async function dropFile(page, file) {
  const name = file.split('/').pop();
  const transfer = await page.evaluateHandle(
    ({ text, name }) => {
      const dt = new DataTransfer();
      dt.items.add(new File([text], name, { type: 'text/plain' }));
      return dt;
    },
    { text: readFileSync(file, 'utf8'), name },
  );
  await page.dispatchEvent('body', 'drop', { dataTransfer: transfer });
  await page.waitForFunction((n) => document.querySelector('#verdict')?.textContent.endsWith(n), name);
}

// What the page shows of a result: figures, plots, clouds, snippets,
// report and outputs.
async function resultShown(page) {
  return page.evaluate(() => {
    const q = (sel) => document.querySelector(sel);
    return {
      figures: document.querySelectorAll('#figures [data-name]:not([data-name="input"])').length,
      outcomeHidden: q('#outcome').hidden,
      normDots: document.querySelectorAll('#norms circle').length,
      normsSvg: q('#norms').innerHTML,
      cloud: window.magcal.views.cal.count,
      snippetC: q('#snippet-c').textContent,
      snippetRust: q('#snippet-rust').textContent,
      report: q('#report').textContent,
      enabled: ['download', 'copy-c', 'copy-rust', 'send'].filter((id) => !q(`#${id}`).disabled),
      result: window.magcal.result,
    };
  });
}

// A refusal shows only the refusal: nothing of an earlier result is left.
async function assertCleared(page) {
  const r = await resultShown(page);
  assert.equal(r.figures, 0, 'figures of an earlier fit');
  assert.ok(r.outcomeHidden, 'the plots and outputs are hidden');
  assert.equal(r.normDots, 0, 'norm plot');
  assert.equal(r.normsSvg, '', 'norm plot');
  assert.equal(r.cloud, 0, 'calibrated cloud');
  assert.deepEqual([r.snippetC, r.snippetRust, r.report], ['', '', ''], 'snippets and report');
  assert.deepEqual(r.enabled, [], 'download, copy and send buttons');
  assert.equal(r.result, null);
  assert.doesNotMatch(await page.textContent('#message'), /Warning/);
}

// A good fit, to be cleared by what follows.
async function goodFit(page) {
  await openFile(page, join(REAL, 'icm20948_mag_300.csv'));
  assert.match(await page.textContent('#verdict'), /^Calibrated: /);
  const r = await resultShown(page);
  assert.ok(r.figures > 10 && r.normDots > 250 && r.cloud > 250, JSON.stringify({ ...r, result: null }));
  assert.ok(r.snippetC.includes('magcal_apply') && r.snippetRust.includes('Calibration::new'));
  assert.deepEqual(r.enabled, ['download', 'copy-c', 'copy-rust']);
}

// The CLI's reason without its advice in parentheses.
const reason = (cliLine) => cliLine.replace(/^magcal: /, '').replace(/ \([^()]*\)$/, '');

test('a planar recording after a good fit: the refusal clears every result and offers the planar fit, which is magcal planar', async () => {
  const { page, errors, context } = await openPage();
  await goodFit(page);

  const file = join(REAL, 'planar_243.txt');
  await dropFile(page, file);
  assert.match(await page.textContent('#verdict'), /^Refused: planar_243.txt/);
  await assertCleared(page);
  // The CLI's reason; the advice names what the page offers, no command.
  const [code, cliLine] = magcal(file);
  assert.equal(code, 3);
  const message = await page.textContent('#message');
  assert.ok(message.startsWith(reason(cliLine)), `${message} | ${cliLine}`);
  assert.doesNotMatch(message, /magcal|--\w|'/);
  assert.match(message, /fit it as planar\)$/);
  assert.equal(await page.textContent('#offer-fit'), 'Fit as planar (turns about one axis)');
  assert.ok(await page.isVisible('#offer-fit'));
  await page.screenshot({ path: join(SHOTS, 'refused-planar_243.png'), fullPage: true });

  // The offered fit runs and shows what `magcal planar` gives.
  await page.click('#offer-fit');
  await page.waitForFunction(() => document.querySelector('#verdict').textContent.startsWith('Calibrated (planar)'));
  assert.equal(await page.inputValue('#mode'), 'planar');
  const [pcode, cli] = magcalPlanar(file);
  assert.equal(pcode, 0);
  await assertSamePlanar(page, cli);
  // The limits quoted beside the figures are the core's.
  const limits = await page.evaluate(() => window.magcal.core.info().limits.planar);
  const figuresText = await page.textContent('#figures');
  assert.doesNotMatch(figuresText, /undefined|NaN/);
  for (const quoted of [`refused above ${limits.refuse_fit_error}`, `refused above ${limits.refuse_not_planar} (not turns`, `of ${limits.sectors} sectors`, `refused below ${limits.min_sectors}`]) {
    assert.ok(figuresText.includes(quoted), `${quoted} in ${figuresText}`);
  }
  await page.screenshot({ path: join(SHOTS, 'planar-planar_243.png'), fullPage: true });
  // The download is that JSON, and `magcal apply` reads it: its headings
  // are those the page computed from it.
  const [download] = await Promise.all([page.waitForEvent('download'), page.click('#download')]);
  const saved = JSON.parse(readFileSync(await download.path(), 'utf8'));
  assert.deepEqual(saved, cli);
  const calFile = join(scratch, 'planar_243.json');
  writeFileSync(calFile, JSON.stringify(saved));
  const applied = execFileSync(MAGCAL, ['apply', calFile, file], { encoding: 'utf8' }).trim().split('\n').slice(1);
  const headings = await page.evaluate(() => window.magcal.result.headings);
  assert.equal(applied.length, headings.length);
  applied.forEach((row, i) => assertClose(headings[i], Number(row.split(',')[2]), 1e-9, `heading of row ${i}`));
  // No C (the C API has no planar calibration), and it says so; the Rust
  // snippet builds and gives headings.
  const r = await resultShown(page);
  assert.equal(r.snippetC, '');
  assert.match(await page.textContent('#c-summary'), /no planar calibration/);
  assert.deepEqual(r.enabled, ['download', 'copy-rust']);
  checkRustSnippet(r.snippetRust, 'pub fn heading() -> Result<f32, Error> {\n    Ok(calibration()?.heading_deg([1i16, 2, 3]))\n}\n');
  // Every row in the calibrated cloud (the file has no unreadable line).
  assert.equal(r.cloud, readFileSync(file, 'utf8').trim().split('\n').length);

  // The up axis and heading 0 as the CLI's --up and --align.
  await page.selectOption('#up', 'z');
  await page.fill('#align', '10:45');
  await page.press('#align', 'Enter');
  await page.waitForFunction(() => window.magcal.result?.fit.up === 'z' && window.magcal.result.fit.zero_deg !== 0);
  const [, aligned] = magcalPlanar(file, '--up', 'z', '--align', '10:45');
  await assertSamePlanar(page, aligned);
  assertClose(await page.evaluate(() => window.magcal.result.headings[10]), 45, 1e-9, 'heading of row 10');

  // A 3-D recording in planar mode is refused (after a good planar fit),
  // everything cleared, and the 3-D fit offered.
  const full = join(REAL, 'icm20948_mag_300.csv');
  await openFile(page, full);
  assert.match(await page.textContent('#verdict'), /^Refused/);
  await assertCleared(page);
  const [, planarLine] = magcalPlanar(full, '--up', 'z');
  assert.equal(`magcal: ${await page.textContent('#message')}`, planarLine);
  assert.equal(await page.textContent('#offer-fit'), 'Fit in 3-D (turns in every direction)');
  await page.click('#offer-fit');
  await page.waitForFunction(() => document.querySelector('#verdict').textContent.startsWith('Calibrated: '));
  assertSameCalibration(await shown(page), magcal(full)[1], 1e-9);
  assert.deepEqual(errors, []);
  await context.close();
});

async function assertSamePlanar(page, cli) {
  const v = await page.evaluate(() =>
    Object.fromEntries([...document.querySelectorAll('#figures [data-value]')].map((e) => [e.dataset.name, Number(e.dataset.value)])),
  );
  for (let i = 0; i < 3; i += 1) {
    assertClose(v[`a${i}`], cli.axis[i], 1e-12, `axis[${i}]`);
    assertClose(v[`c${i}`], cli.centre[i], 1e-12, `centre[${i}]`);
    for (let r = 0; r < 2; r += 1) assertClose(v[`K${r}${i}`], cli.matrix[r][i], 1e-12, `K[${r}][${i}]`);
  }
  assertClose(v.zero, cli.zero_deg, 1e-12, 'zero');
  assertClose(v['field in the plane'], cli.plane_strength, 1e-12, 'field in the plane');
  assertClose(v['fit error'], cli.fit_error, 1e-12, 'fit error');
  assertClose(v.flatness, cli.flatness, 1e-12, 'flatness');
  assert.equal(v.sectors, cli.sectors);
  const samples = await page.textContent('[data-name="samples"]');
  assert.equal(samples, `${cli.samples_used} used of 243: ${cli.samples_dropped} dropped, ${cli.screened} screened, ${cli.rejected} rejected`);
}

test('a still device after a good fit: the refusal clears every result and says why', async () => {
  const { page, errors, context } = await openPage();
  await goodFit(page);
  // One reading repeated with noise of about 1.5 counts (a fixed
  // pseudo-random sequence), as a board left lying on the desk.
  let seed = 12345;
  const noise = () => {
    seed = (seed * 1103515245 + 12345) % 2 ** 31;
    return (seed / 2 ** 31 - 0.5) * 5;
  };
  const rows = Array.from({ length: 400 }, () => [210 + noise(), -35 + noise(), 480 + noise()].map((v) => v.toFixed(2)).join(','));
  const file = join(scratch, 'still.csv');
  writeFileSync(file, `x,y,z\n${rows.join('\n')}\n`);
  await dropFile(page, file);
  assert.match(await page.textContent('#verdict'), /^Refused: still.csv/);
  await assertCleared(page);
  const [code, cliLine] = magcal(file);
  assert.equal(code, 3);
  const message = await page.textContent('#message');
  assert.equal(`magcal: ${message}`, cliLine);
  assert.doesNotMatch(message, /magcal|--\w/);
  assert.ok(await page.isHidden('#offer'), 'no other fit offered');
  assert.match(await page.textContent('#figures'), /^400 rows from x,y,z /);
  assert.deepEqual(errors, []);
  await context.close();
});

// `rows` with its first reading repeated `before` times before it and its
// last `after` times after it, each with a count of noise (-1, 0, 0 or +1
// per axis, a fixed linear congruential generator): the device lying still
// on the desk before and after its turns, as people record.
function withStillEnds(rows, before, after) {
  let state = 12345;
  const still = (r, n) =>
    Array.from({ length: n }, () =>
      r.map((v) => {
        state = (Math.imul(state, 1664525) + 1013904223) >>> 0;
        return v + [-1, 0, 0, 1][state >>> 30];
      }),
    );
  return [...still(rows[0], before), ...rows, ...still(rows[rows.length - 1], after)];
}

test('a log lying still before and after its turns shows the rows set aside as magcal counts them; one that hardly moved is refused as such', async () => {
  const { page, errors, context } = await openPage();
  const rows = readFileSync(join(REAL, 'icm20948_mag_300.csv'), 'utf8')
    .trim()
    .split('\n')
    .map((line) => line.split(',').map(Number));
  const csv = (r) => `${r.map((row) => row.join(',')).join('\n')}\n`;
  const file = join(scratch, 'still_ends.csv');
  writeFileSync(file, csv(withStillEnds(rows, 600, 1200)));
  await openFile(page, file);
  assert.match(await page.textContent('#verdict'), /^Calibrated: still_ends.csv/);
  const [code, cli] = magcal(file);
  assert.equal(code, 0);
  assert.ok(cli.dwell > 0, JSON.stringify(cli));
  assertSameCalibration(await shown(page), cli, 1e-9);
  // The counts, as the CLI gives them, and where the device lay still as
  // its text report names it.
  assert.equal(
    await page.textContent('[data-name="samples"]'),
    `${cli.samples_used} used of 2100: ${cli.samples_dropped} dropped, ${cli.dwell} still, ${cli.screened} screened, ${cli.rejected} rejected`,
  );
  const report = execFileSync(MAGCAL, ['fit', file], { encoding: 'utf8' });
  const where = report.match(/ still \(set aside: the device lay still (within .*?\))\), \d+ screened/)[1];
  assert.equal(where.match(/within /g).length, cli.selection.dwell.length);
  const note = await page.textContent('td[data-name="samples"] + td.note');
  assert.equal(note, `still: set aside where the device lay still ${where}`);
  // Each row's class: the still rows drawn in their own colour.
  const classes = await page.evaluate(() => window.magcal.result.classes);
  assert.equal(classes.filter((c) => c === 'dwell').length, cli.dwell);
  assert.equal(await page.locator('#norms circle.dwell').count(), cli.dwell);
  assert.match(await page.innerHTML('#cal-caption'), /<span class="dwell">still/);
  await page.screenshot({ path: join(SHOTS, 'still-ends.png'), fullPage: true });

  // The first reading, one of the turns and the last, each lying still
  // 600 more times: the device hardly moved. A refusal of its own cause.
  const hardly = join(scratch, 'hardly_moved.csv');
  writeFileSync(hardly, csv(withStillEnds([rows[0], rows[150], rows[rows.length - 1]], 600, 600)));
  await dropFile(page, hardly);
  assert.match(await page.textContent('#verdict'), /^Refused: hardly_moved.csv/);
  await assertCleared(page);
  const [refused, cliLine] = magcal(hardly);
  assert.equal(refused, 3);
  const message = await page.textContent('#message');
  assert.equal(`magcal: ${message}`, cliLine);
  assert.match(message, /^calibration refused: the device hardly moved: .*: turn the sensor through all orientations while recording$/);
  assert.ok(await page.isHidden('#offer'), 'no other fit offered');
  assert.match(await page.textContent('#figures'), /^1203 rows from /);
  assert.deepEqual(errors, []);
  await context.close();
});

// A recorded stream as a board running Adafruit's or PJRC's calibration
// sketch prints it: `Raw:` lines of integers, with a banner and other
// lines between. The magnetometer is magcal_25598.txt (a long real 3-D
// recording, units of about 0.7 at full field) times SCALE, rounded; that
// recording has no accelerometer or gyroscope, sent as 0.
const SCALE = 600;
function streamRows() {
  return readFileSync(join(REAL, 'magcal_25598.txt'), 'utf8')
    .trim()
    .split('\n')
    .map((row) => row.trim().split(/\s+/).map((v) => Math.round(Number(v) * SCALE)));
}

function rawStream(rows) {
  const lines = ['Adafruit sensor calibration (test double)'];
  rows.forEach((m, i) => {
    lines.push(`Raw:0,0,0,0,0,0,${m.join(',')}`);
    // A serial line caught half-way, an all-zero glitch and a wild reading.
    if (i === 300) lines.push('Raw:0,0,0,0,0');
    if (i === 310) lines.push('Raw:0,0,0,0,0,0,0,0,0');
    if (i === 320) lines.push('Raw:0,0,0,0,0,0,30000,-30000,30000');
    if (i % 100 === 0) lines.push('Uni:0.000,0.000,0.000,0.0000,0.0000,0.0000,0.000,0.000,0.000');
  });
  return `${lines.join('\r\n')}\r\n`;
}

// navigator.serial replaced by a port that plays `text` back in small
// chunks (from the start at each open) and records what the page writes.
// Like Chromium's, it refuses to close while its readable stream is locked.
// With `more`, a board that goes on sending: after `text` the port waits
// (window.__waiting) until the test sets window.__release, plays `more`,
// and then stays open, silent, until the page cancels the read.
function serialDouble(text, more = null) {
  window.__written = [];
  window.__opens = 0;
  window.__closes = 0;
  const encode = (t) => new TextEncoder().encode(t);
  const wait = (done) =>
    new Promise((r) => {
      const poll = () => (done() ? r() : setTimeout(poll, 5));
      poll();
    });
  const port = {
    readable: null,
    writable: null,
    async open(options) {
      if (this.readable) throw new DOMException('The port is already open.', 'InvalidStateError');
      window.__baud = options.baudRate;
      window.__opens += 1;
      let bytes = encode(text);
      let rest = more === null ? [] : [more];
      let at = 0;
      let cancelled = false;
      this.readable = new ReadableStream({
        async pull(controller) {
          if (at >= bytes.length && more !== null) {
            window.__waiting = true;
            await wait(() => cancelled || (rest.length ? window.__release : false));
            if (cancelled) return;
            if (!rest.length) return;
            bytes = encode(rest.shift());
            at = 0;
          }
          if (at >= bytes.length) {
            controller.close();
            return;
          }
          await new Promise((r) => setTimeout(r, 1));
          controller.enqueue(bytes.slice(at, at + 200));
          at += 200;
        },
        cancel() {
          cancelled = true;
        },
      });
      this.writable = new WritableStream({
        write(chunk) {
          window.__written.push(...chunk);
        },
      });
    },
    async close() {
      if (this.readable?.locked) throw new TypeError('Cannot close a port whose readable stream is locked.');
      this.readable = null;
      this.writable = null;
      window.__closes += 1;
    },
  };
  Object.defineProperty(navigator, 'serial', { value: { requestPort: async () => port } });
}

// MotionCal's packet built here from a calibration, independently of the
// page: header, 16 little-endian floats, CRC-16 by a lookup table.
function motioncalPacket(cal) {
  const table = Array.from({ length: 256 }, (_, n) => {
    let c = n;
    for (let k = 0; k < 8; k += 1) c = c & 1 ? (c >>> 1) ^ 0xa001 : c >>> 1;
    return c;
  });
  const crc16 = (bytes) => bytes.reduce((c, b) => (c >>> 8) ^ table[(c ^ b) & 0xff], 0xffff);
  const buf = new DataView(new ArrayBuffer(68));
  buf.setUint8(0, 117);
  buf.setUint8(1, 84);
  const rho = cal.field_strength;
  const w = cal.soft_iron;
  const values = [0, 0, 0, 0, 0, 0, ...cal.hard_iron.map((b) => b / 10), rho / 10,
    rho * w[0][0], rho * w[1][1], rho * w[2][2], rho * w[0][1], rho * w[0][2], rho * w[1][2]];
  values.forEach((v, i) => buf.setFloat32(2 + 4 * i, v, true));
  const bytes = new Uint8Array(buf.buffer);
  buf.setUint16(66, crc16(bytes.slice(0, 66)), true);
  assert.equal(crc16(bytes), 0);
  return [...bytes];
}

test('a Raw: stream through the serial port: progress, coverage, fit, and send to board', async () => {
  const rows = streamRows();
  // A sensor's wild start-up value first, after the sketch's banner.
  const stream = rawStream(rows).replace('\r\n', '\r\nRaw:0,0,0,0,0,0,30000,-30000,30000\r\n');
  const { page, errors, context } = await openPage([serialDouble.toString(), `serialDouble(${JSON.stringify(stream)});`].join('\n'));
  await page.click('#connect');
  await page.waitForFunction(() => window.magcal.streamEnded === true, null, { timeout: 60_000 });
  assert.equal(await page.evaluate(() => window.__baud), 115200);

  const p = await page.evaluate(() => window.magcal.progress);
  const rawLines = stream.split('\r\n').filter((l) => l.startsWith('Raw:')).length;
  assert.equal(p.lines, rawLines);
  assert.equal(p.skipped, stream.split('\r\n').filter((l) => l && !l.startsWith('Raw:')).length);
  assert.ok(p.ready && p.percent === 100, JSON.stringify(p));
  assert.ok(p.cells_visited >= 36 && p.samples >= 100 && p.samples < rawLines, JSON.stringify(p));
  // What the page shows of it.
  assert.equal(await page.evaluate(() => document.querySelector('#progress').value), 100);
  assert.equal(await page.locator('#cells div.visited').count(), p.cells_visited);
  const progressText = await page.textContent('#progress-text');
  assert.match(progressText, new RegExp(`^100 %: ${p.samples} samples kept of ${rawLines}`));
  // The planted bad lines were refused, each for its reason, and said so.
  assert.equal(p.refused.not_finite, 1, JSON.stringify(p.refused));
  assert.equal(p.refused.glitch, 1, JSON.stringify(p.refused));
  assert.ok(p.refused.outlier >= 1, JSON.stringify(p.refused));
  // The wild first reading drags the first samples' centre away: the
  // collection starts over, and the page says so. (The board lying still
  // at the start of the recording adds one sample and no restart.)
  assert.ok(p.refused.restarted >= 1, JSON.stringify(p));
  assert.match(progressText, new RegExp(`restarts: ${p.refused.restarted} \\(.*; ${p.discarded} samples discarded\\)`));
  assert.match(progressText, new RegExp(`not kept: cut short or not numbers: 1, glitches \\(zeros, rails\\): 1, outliers \\(far from the others\\): ${p.refused.outlier}`));

  // The final fit is magcal's fit of the samples the collector kept.
  assert.match(await page.textContent('#verdict'), /^Calibrated/);
  const kept = await page.evaluate(() => window.magcal.result.raw);
  assert.equal(kept.length, p.samples);
  const keptFile = join(scratch, 'kept.csv');
  writeFileSync(keptFile, `${kept.map((s) => s.join(',')).join('\n')}\n`);
  const [code, cli] = magcal(keptFile);
  assert.equal(code, 0);
  assertSameCalibration(await shown(page), cli, 1e-9);
  // ... and close to magcal's fit of the whole recording.
  const wholeFile = join(scratch, 'stream.csv');
  writeFileSync(wholeFile, `${rows.map((m) => m.join(',')).join('\n')}\n`);
  const [, whole] = magcal(wholeFile);
  for (let i = 0; i < 3; i += 1) {
    assert.ok(Math.abs(cli.hard_iron[i] - whole.hard_iron[i]) < 0.05 * whole.field_strength, `b[${i}]`);
  }
  await page.screenshot({ path: join(SHOTS, 'serial-stream.png'), fullPage: true });

  // Send to board: the 68 bytes MotionCal would send.
  assert.ok(!(await page.isDisabled('#send')));
  await page.click('#send');
  await page.waitForFunction(() => window.magcal.sent === 1);
  const written = await page.evaluate(() => window.__written);
  assert.deepEqual(written, motioncalPacket(cli));
  // What the board does with it (Adafruit_Sensor_Calibration): uT from the
  // Raw: counts, less the hard iron, times the soft iron: the field's
  // strength, on every sample the fit used.
  const view = new DataView(new Uint8Array(written).buffer);
  const f = (i) => view.getFloat32(2 + 4 * i, true);
  const V = [f(6), f(7), f(8)];
  const B = f(9);
  const S = [[f(10), f(13), f(14)], [f(13), f(11), f(15)], [f(14), f(15), f(12)]];
  const classes = await page.evaluate(() => window.magcal.result.classes);
  const off = kept
    .filter((_, i) => classes[i] === 'used')
    .map((y) => {
      const d = y.map((v, k) => v / 10 - V[k]);
      const m = S.map((row) => row[0] * d[0] + row[1] * d[1] + row[2] * d[2]);
      return Math.abs(Math.hypot(...m) / B - 1);
    })
    .sort((a, b) => a - b);
  assert.ok(off[Math.floor(off.length / 2)] < 0.02 && off[off.length - 1] < 0.1, `median ${off[Math.floor(off.length / 2)]}`);
  assert.deepEqual(errors, []);
  await context.close();
});

// A board turned about a steady field: `n` Raw: lines on an ellipsoid
// about `centre`, in a turning board's order (a spiral from pole to pole).
function turningBoard(n, centre) {
  let phi = 0;
  const lines = [];
  for (let i = 0; i < n; i += 1) {
    const z = 1 - (2 * (i + 0.5)) / n;
    const r = Math.sqrt(1 - z * z);
    phi += 3.6 / Math.sqrt(n) / r;
    const m = [centre[0] + 400 * r * Math.cos(phi), centre[1] + 460 * r * Math.sin(phi), centre[2] + 430 * z];
    lines.push(`Raw:0,0,0,0,0,0,${m.map(Math.round).join(',')}`);
  }
  return `${lines.join('\r\n')}\r\n`;
}

test('a live refit that is refused takes the earlier calibration off the page, send to board too', async () => {
  // A good collection; then the board's hard iron moves by about half the
  // field (a magnet or a steel mount brought near), and the board goes on
  // turning and sending.
  const good = turningBoard(600, [120, -80, 35]);
  const moved = turningBoard(600, [320, 120, 35]);
  const init = [serialDouble.toString(), `serialDouble(${JSON.stringify(good)}, ${JSON.stringify(moved)});`].join('\n');
  const { page, errors, context } = await openPage(init);
  await page.click('#connect');
  await page.waitForFunction(() => window.__waiting === true && window.magcal.result?.status === 'ok', null, { timeout: 60_000 });
  assert.match(await page.textContent('#verdict'), /^Calibrated: serial/);
  assert.deepEqual((await resultShown(page)).enabled, ['download', 'copy-c', 'copy-rust', 'send']);

  await page.evaluate(() => {
    window.__release = true;
  });
  // The automatic refits of the collection that now holds both: refused
  // while the board still sends (the stream has not ended).
  await page.waitForFunction(() => document.querySelector('#verdict').textContent.startsWith('Refused'), null, { timeout: 60_000 });
  assert.equal(await page.evaluate(() => window.magcal.streamEnded), false);
  assert.match(await page.textContent('#verdict'), /^Refused: serial/);
  await assertCleared(page);
  // Both read at once: the board still sends, and a later refit may
  // replace both between two reads.
  const [message, status] = await page.evaluate(() => ['#message', '#status'].map((id) => document.querySelector(id).textContent));
  assert.match(message, /^calibration refused: /);
  assert.doesNotMatch(message, /magcal|--\w/);
  assert.equal(status, message);
  // The send button stays off, and a click sends nothing.
  await page.dispatchEvent('#send', 'click');
  assert.deepEqual(await page.evaluate(() => window.__written), []);
  await page.screenshot({ path: join(SHOTS, 'serial-refit-refused.png'), fullPage: true });

  await page.click('#disconnect');
  await page.waitForFunction(() => window.magcal.streamEnded === true);
  assert.match(await page.textContent('#verdict'), /^Refused: serial/);
  await assertCleared(page);
  assert.deepEqual(errors, []);
  await context.close();
});

test('the time of a fit in the page (a measurement, printed for docs/benchmarks.md)', async () => {
  const { page, context } = await openPage();
  for (const name of ['icm20948_mag_300.csv', 'magcal_25598.txt']) {
    const bytes = [...readFileSync(join(REAL, name))];
    const figures = await page.evaluate(
      ({ bytes, name }) => {
        const data = new Uint8Array(bytes);
        const runs = [];
        for (let k = 0; k < 11; k += 1) {
          const t0 = performance.now();
          const doc = window.magcal.core.fit(data, { name, precision: 'f32' });
          if (doc.status !== 'ok') throw new Error(`${name}: ${doc.message}`);
          runs.push([doc.fit.timing_us / 1000, performance.now() - t0]);
        }
        const median = (v) => v.sort((a, b) => a - b)[(v.length - 1) / 2];
        return { fit: median(runs.map((r) => r[0])), call: median(runs.map((r) => r[1])) };
      },
      { bytes, name },
    );
    console.log(`web fit ${name} (f32, adc2): fit ${figures.fit.toFixed(2)} ms, whole call (parse, fit, JSON) ${figures.call.toFixed(1)} ms, median of 11`);
  }
  await context.close();
});

test('disconnecting mid-stream closes the port; connecting again starts a new collection', async () => {
  const stream = rawStream(streamRows());
  const { page, errors, context } = await openPage([serialDouble.toString(), `serialDouble(${JSON.stringify(stream)});`].join('\n'));
  await page.click('#connect');
  await page.waitForFunction(() => (window.magcal.progress?.samples ?? 0) > 150);
  await page.click('#disconnect');
  await page.waitForFunction(() => !document.querySelector('#connect').disabled);
  assert.equal(await page.evaluate(() => window.__closes), 1);
  assert.doesNotMatch(await page.textContent('#status'), /did not close|Internal error/);
  const before = await page.evaluate(() => window.magcal.progress.lines);
  assert.ok(before < 25_000, `${before} lines read before the disconnect`);

  // Again: the collection starts from nothing and runs to the end.
  await page.click('#connect');
  await page.waitForFunction(() => window.magcal.streamEnded === true, null, { timeout: 90_000 });
  const p = await page.evaluate(() => window.magcal.progress);
  assert.equal(await page.evaluate(() => window.__opens), 2);
  assert.equal(p.lines, stream.split('\r\n').filter((l) => l.startsWith('Raw:')).length, JSON.stringify(p));
  assert.match(await page.textContent('#verdict'), /^Calibrated/);
  assert.deepEqual(errors, []);
  await context.close();
});
