// The page: inputs (a file, a serial port), the views, the result and the
// outputs. Every number shown comes from the core (core.js); this file
// draws and formats.

import { loadCore, CoreRestarted } from './core.js';
import { Cloud } from './cloud.js';

const $ = (id) => document.getElementById(id);
// A line longer than this is no MotionCal line (a wrong baud rate gives
// noise without newlines): it is dropped.
const MAX_LINE = 4096;

const core = await loadCore('./mag_cal_web.wasm');
const info = core.info();
const rawView = new Cloud($('raw-view'), { sphere: false });
const calView = new Cloud($('cal-view'), { sphere: true });

// What the page shows; read by the browser tests.
const state = {
  source: null, // 'file' or 'serial'
  result: null, // the core's fit document shown (null when none is)
  progress: null, // the collector's last progress
  raw: [], // samples received over serial
  sent: 0, // packets written to the board
};
state.core = core;
state.views = { raw: rawView, cal: calView };
window.magcal = state;

for (const m of info.methods) $('method').append(new Option(m, m));
buildCells();

function options(name) {
  return {
    name,
    mode: $('mode').value,
    precision: $('precision').value,
    method: $('method').value,
    plain: $('plain').checked,
    columns: $('columns').value.trim(),
    up: $('up').value,
    align: $('align').value.trim(),
  };
}

const planarMode = () => $('mode').value === 'planar';

// Each fit's own controls: method and outlier handling for the 3-D fit,
// up axis and heading 0 for the planar one.
function syncMode() {
  const planar = planarMode();
  for (const id of ['method', 'plain']) $(id).disabled = planar;
  for (const id of ['up', 'align']) $(id).disabled = !planar;
}

function setStatus(text, kind = '') {
  $('status').textContent = text;
  $('status').className = `status ${kind}`;
}

// ---- a file ---------------------------------------------------------------

let lastFile = null;

async function openFile(file) {
  await stopSerial();
  lastFile = { name: file.name, bytes: new Uint8Array(await file.arrayBuffer()) };
  fitFile();
}

function fitFile() {
  if (!lastFile) return;
  state.source = 'file';
  $('live').hidden = true;
  let doc;
  try {
    doc = core.fit(lastFile.bytes, options(lastFile.name));
  } catch (err) {
    coreFailed(err);
    return;
  }
  rawView.setPoints(doc.raw ?? [], doc.classes, ...frame(doc));
  showResult(doc, lastFile.name);
}

// The centre and radius of the raw view for a fit: the hard iron and the
// field, or the planar fit's centre and field in the plane.
function frame(doc) {
  if (doc?.status !== 'ok') return [null, null];
  return doc.mode === 'planar' ? [doc.fit.centre, doc.fit.plane_strength] : [doc.fit.hard_iron, doc.fit.field_strength];
}

function refit() {
  if (state.source === 'serial') fitLive(true);
  else fitFile();
}

$('file').addEventListener('change', (e) => {
  if (e.target.files.length) openFile(e.target.files[0]);
  // Choosing the same file again (changed, or after another) reads it again.
  e.target.value = '';
});
document.addEventListener('dragover', (e) => e.preventDefault());
document.addEventListener('drop', (e) => {
  e.preventDefault();
  if (e.dataTransfer.files.length) openFile(e.dataTransfer.files[0]);
});
for (const id of ['precision', 'method', 'plain', 'columns', 'mode', 'up', 'align']) {
  $(id).addEventListener('change', () => {
    syncMode();
    refit();
  });
}

// ---- a board over WebSerial -----------------------------------------------

let port = null;
let reader = null;
let piping = null; // the current pipe from the port into the line decoder
let session = 0; // one per connection: a stale read loop must not touch a new one
let acceptedSinceFit = 0;

// What a failed call of the core means for the page.
function coreFailed(err) {
  clearResult();
  if (err instanceof CoreRestarted) {
    state.raw = [];
    state.progress = null;
    setStatus(`Internal error: ${err.message}; the collection starts again (please report it).`, 'bad');
  } else {
    setStatus(`Internal error: ${err.message} (please report it).`, 'bad');
  }
}

async function connect() {
  if (!('serial' in navigator)) {
    setStatus('This browser has no WebSerial: use Chrome, Edge or another Chromium browser, on https or localhost.', 'bad');
    return;
  }
  try {
    port = await navigator.serial.requestPort();
    await port.open({ baudRate: 115200 });
  } catch (err) {
    setStatus(`No port opened: ${err.message}`, 'bad');
    port = null;
    return;
  }
  session += 1;
  state.source = 'serial';
  state.raw = [];
  clearResult();
  $('result').hidden = true;
  state.streamEnded = false;
  lastFile = null;
  acceptedSinceFit = 0;
  core.liveReset();
  $('live').hidden = false;
  $('connect').disabled = true;
  $('disconnect').disabled = false;
  setStatus('Connected: turn the board slowly in every direction.');
  readLines(session, port);
}

// Reads lines until the stream ends, the user disconnects or a fatal error.
// Errors the Web Serial API calls non-fatal (buffer overrun, framing,
// parity, break) give the port a new readable stream: reading goes on.
async function readLines(id, from) {
  let failure = null;
  while (id === session && from.readable) {
    const decoder = new TextDecoderStream();
    piping = from.readable.pipeTo(decoder.writable).catch(() => {});
    reader = decoder.readable.getReader();
    let pending = '';
    let end = false;
    try {
      for (;;) {
        const { value, done } = await reader.read();
        if (done) {
          end = true;
          break;
        }
        pending += value;
        let nl;
        while ((nl = pending.indexOf('\n')) >= 0) {
          onLine(pending.slice(0, nl));
          pending = pending.slice(nl + 1);
        }
        if (pending.length > MAX_LINE) pending = '';
        redrawLive();
      }
    } catch (err) {
      failure = err;
    } finally {
      reader.releaseLock();
      reader = null;
    }
    if (pending && id === session) onLine(pending);
    await piping;
    const nonFatal = ['BufferOverrunError', 'FramingError', 'ParityError', 'BreakError'];
    if (end || !failure || !nonFatal.includes(failure.name)) break;
    failure = null;
  }
  if (id !== session) return;
  fitLive(true);
  state.streamEnded = true;
  if (failure) setStatus(`The serial port stopped: ${failure.message}`, 'bad');
}

function onLine(line) {
  let r;
  try {
    r = core.liveLine(line);
  } catch (err) {
    coreFailed(err);
    return;
  }
  state.progress = r.progress;
  if (r.kind !== 'raw') return;
  if (r.sample.every(Number.isFinite)) state.raw.push(r.sample);
  if (r.offer === 'accepted') acceptedSinceFit += 1;
}

let redrawPending = false;
function redrawLive() {
  if (redrawPending) return;
  redrawPending = true;
  requestAnimationFrame(() => {
    redrawPending = false;
    const p = state.progress;
    if (!p) return;
    showProgress(p);
    rawView.setPoints(state.raw, null, ...frame(state.result));
    // Refit as the collection grows, once it is ready (planar: the
    // collector's coverage of the sphere never is; the fit says when the
    // turns suffice).
    if ((p.ready || planarMode()) && acceptedSinceFit >= 25) fitLive(false);
  });
}

function fitLive(force) {
  if (state.source !== 'serial' || !state.progress) return;
  if (!force && !state.progress.ready && !planarMode()) return;
  acceptedSinceFit = 0;
  let doc;
  try {
    doc = core.liveFit(options('serial'));
  } catch (err) {
    coreFailed(err);
    return;
  }
  // Once a result is on the page, every refit replaces it: a refused one
  // takes the earlier calibration off (its snippets, downloads and send to
  // board), as a refused file does. Before any, an automatic refit that is
  // refused leaves the page to the progress (a planar collection is
  // refused until its turns suffice).
  if (doc.status === 'ok' || force || !$('result').hidden) showResult(doc, 'serial');
}

// Disconnect: the read loop ends (and fits what it has), the pipe lets go
// of the port's stream, then the port closes.
async function stopSerial() {
  if (!port) return;
  const closing = port;
  port = null;
  try {
    await reader?.cancel();
  } catch (_) {
    /* already ended */
  }
  await piping;
  try {
    await closing.close();
  } catch (err) {
    setStatus(`The port did not close: ${err.message}`, 'bad');
  }
  $('connect').disabled = false;
  $('disconnect').disabled = true;
  $('send').disabled = true;
}

$('connect').addEventListener('click', connect);
$('disconnect').addEventListener('click', stopSerial);
// A board unplugged: its port goes away.
navigator.serial?.addEventListener?.('disconnect', (e) => {
  if (e.target === port) stopSerial();
});

// ---- coverage ---------------------------------------------------------------

function buildCells() {
  const grid = $('cells');
  // North (band 5) at the top; sectors of longitude left to right.
  grid.style.gridTemplateColumns = `repeat(${info.sectors}, 1.4rem)`;
  $('cells-hint').textContent =
    `The core's collector (up to ${info.live_capacity} samples): ${info.cells} cells of equal area, ` +
    `${info.bands} bands of latitude (north at the top) by ${info.sectors} sectors of longitude, ` +
    'blue once a kept sample points into one.';
  const width = 360 / info.sectors;
  for (let band = info.bands - 1; band >= 0; band -= 1) {
    for (let sector = 0; sector < info.sectors; sector += 1) {
      const cell = document.createElement('div');
      cell.dataset.cell = band * info.sectors + sector;
      cell.title = `band ${band} from the south, longitude ${sector * width}-${(sector + 1) * width} deg`;
      grid.append(cell);
    }
  }
}

// The collector's refusals in words (too_close, the usual one, left out).
const REFUSED = {
  not_finite: 'cut short or not numbers',
  glitch: 'glitches (zeros, rails)',
  outlier: 'outliers (far from the others)',
  full: 'after the collector was full',
};

function showProgress(p) {
  $('progress').value = p.percent;
  const refused = Object.entries(REFUSED)
    .filter(([name]) => p.refused[name] > 0)
    .map(([name, words]) => `${words}: ${p.refused[name]}`);
  $('progress-text').textContent =
    `${p.percent} %: ${p.samples} samples kept of ${p.lines} Raw: lines, ` +
    `${p.cells_visited} of ${p.cells} cells${p.ready ? ', ready' : ''}` +
    (refused.length ? `; not kept: ${refused.join(', ')}` : '') +
    (p.refused.restarted
      ? `; restarts: ${p.refused.restarted} (a wild reading among the first, or a long run of readings far from those kept, as after the sensor moved; ${p.discarded} samples discarded)`
      : '');
  for (const cell of $('cells').children) {
    cell.classList.toggle('visited', p.visited[cell.dataset.cell]);
  }
}

// ---- the result -------------------------------------------------------------

const digits = (v, n = 7) => (Number.isFinite(v) ? Number(v.toPrecision(n)).toString() : String(v));

// Text from the user's file (header names, unreadable fields) as HTML
// text, never markup.
function html(text) {
  const entities = { '&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;', "'": '&#39;' };
  return String(text).replace(/[&<>"']/g, (c) => entities[c]);
}

function figure(name, value, note = '') {
  const v = typeof value === 'number' ? digits(value) : value;
  const data = typeof value === 'number' ? ` data-value="${value}"` : '';
  return `<tr><th>${name}</th><td data-name="${name}"${data}>${v}</td><td class="note">${note}</td></tr>`;
}

const RAW_CAPTION = {
  '3d': 'Raw samples, centred on b and divided by the field strength (before a fit: centred on their middle, scaled by their median distance)',
  planar: "Raw samples, centred on the planar fit's centre and divided by the field in the plane",
};
const CAL_CAPTION = {
  '3d': 'Calibrated samples on the unit sphere: <span class="used">used</span>, <span class="rejected">rejected</span>, <span class="screened">screened</span>, <span class="dwell">still (set aside)</span>',
  planar: 'Planar calibration: u = K (y − centre) of every sample, on the unit circle (z = 0); the planar fit does not mark rows',
};
const NORMS_CAPTION = {
  '3d': '|W (y − b)| per sample, in input order (1 = the field)',
  planar: '|K (y − centre)| per sample, in input order (1 = the field in the plane)',
};
const OFFER = {
  planar: ['Fit as planar (turns about one axis)', () => `with the up axis set above (now ${$('up').selectedOptions[0].text})`],
  '3d': ['Fit in 3-D (turns in every direction)', () => ''],
};

// Takes every result off the page (figures, warnings, plots, 3-D cloud,
// snippets, report, downloads, send to board): before any fit is shown,
// so that a refusal shows only the refusal.
function clearResult() {
  state.result = null;
  $('verdict').textContent = '';
  $('message').textContent = '';
  $('message').className = 'message';
  $('offer').hidden = true;
  $('figures').innerHTML = '';
  $('outcome').hidden = true;
  $('norms').innerHTML = '';
  $('norms-caption').textContent = NORMS_CAPTION['3d'];
  calView.setPoints([], null, null, null);
  $('cal-caption').innerHTML = CAL_CAPTION['3d'];
  $('raw-caption').textContent = RAW_CAPTION['3d'];
  for (const id of ['snippet-c', 'snippet-rust', 'report', 'send-status']) $(id).textContent = '';
  $('c-summary').textContent = 'C';
  $('report-command').textContent = 'magcal fit';
  for (const id of ['download', 'copy-c', 'copy-rust', 'send']) {
    $(id).disabled = true;
    $(id).title = '';
  }
}

function showResult(doc, name) {
  clearResult();
  $('result').hidden = false;
  const ok = doc.status === 'ok';
  $('verdict').textContent = ok
    ? `Calibrated${doc.mode === 'planar' ? ' (planar)' : ''}: ${name}`
    : doc.status === 'refused'
      ? `Refused: ${name}`
      : `Not read: ${name}`;
  $('verdict').className = ok ? 'good' : 'bad';
  if (!ok) {
    $('message').textContent = doc.message;
    $('message').className = 'message bad';
    // The other fit, where the refusal's cause says the motion suits it.
    if (OFFER[doc.offer]) {
      const [label, hint] = OFFER[doc.offer];
      $('offer-fit').textContent = label;
      $('offer-fit').dataset.mode = doc.offer;
      $('offer-hint').textContent = hint();
      $('offer').hidden = false;
    }
    $('figures').innerHTML = doc.columns
      ? `<p>${doc.rows} rows from ${html(doc.columns)}</p>${doc.skipped ? `<p data-name="input">${html(doc.skipped)}</p>` : ''}`
      : '';
    setStatus(doc.message, 'bad');
    return;
  }
  state.result = doc;
  $('outcome').hidden = false;
  $('message').textContent = warningText(doc);
  $('message').className = `message ${doc.warnings.length ? 'warn' : ''}`;
  $('download').disabled = false;
  $('copy-rust').disabled = false;
  $('snippet-rust').textContent = doc.snippets.rust;
  $('report').textContent = doc.text;
  $('cal-caption').innerHTML = CAL_CAPTION[doc.mode];
  $('raw-caption').textContent = RAW_CAPTION[doc.mode];
  $('norms-caption').textContent = NORMS_CAPTION[doc.mode];
  calView.setPoints(doc.calibrated, doc.classes, [0, 0, 0], 1);
  drawNorms(doc.norms, doc.classes);
  if (doc.mode === 'planar') showPlanar(doc);
  else show3d(doc);
  const what = doc.mode === 'planar' ? 'Calibrated as planar (heading only)' : 'Calibrated';
  const then = doc.packet ? 'keep turning to refine, or send it' : 'keep turning to refine';
  setStatus(state.source === 'serial' ? `${what} from the board: ${then}.` : `${what}.`, 'good');
}

function show3d(doc) {
  const f = doc.fit;
  const q = f.quality;
  const w = f.soft_iron;
  const lim = info.limits['3d'];
  $('figures').innerHTML = `<table class="figures">
    ${figure('hard iron b', `<span class="vec">${f.hard_iron.map((v, i) => `<span data-name="b${i}" data-value="${v}">${digits(v)}</span>`).join(' ')}</span>`, 'sensor units')}
    ${figure('soft iron W', `<span class="mat">${w.map((row, r) => row.map((v, c) => `<span data-name="W${r}${c}" data-value="${v}">${digits(v)}</span>`).join(' ')).join('<br>')}</span>`, 'W (y − b) on the unit sphere')}
    ${figure('field strength', f.field_strength, 'sensor units')}
    ${figure('radial RMS', q.radial_rms, 'of the field')}
    ${figure('fit error', q.fit_error, `robust sigma; warned above ${lim.warn_fit_error}, refused above ${lim.refuse_fit_error}`)}
    ${figure('coverage', q.coverage, `refused below ${lim.refuse_coverage}; full sphere about 0.33`)}
    ${figure('flatness', q.flatness, `refused below ${lim.refuse_flatness}`)}
    ${figure('distortion', q.distortion, `condition number of M; refused above ${lim.refuse_distortion}`)}
    ${figure('lack of fit', q.lack_of_fit, `systematic misfit; refused above ${lim.refuse_lack_of_fit} when significant`)}
    ${figure('outlier share', q.outlier_share, `refused above ${lim.refuse_outlier_share}`)}
    ${figure('columns', html(doc.columns))}
    ${doc.skipped ? figure('input', html(doc.skipped)) : ''}
    ${figure('samples', `${f.samples_used} used of ${doc.rows}: ${f.samples_dropped} dropped, ${f.dwell} still, ${f.screened} screened, ${f.rejected} rejected`, stillNote(f))}
    ${figure('method', `${f.method} (LS ${f.ls}), ${f.precision}, ${f.robust ? 'robust' : 'plain'}; ${digits(f.timing_us / 1000, 3)} ms`)}
    </table>`;
  $('snippet-c').textContent = doc.snippets.c;
  $('copy-c').disabled = false;
  $('send').disabled = !port;
}

// `v` to `n` significant digits, trailing zeros kept, as magcal's text
// report prints them (its `sig`): fixed for exponents -5 to n - 1,
// otherwise `1.235e4`.
function sig(v, n) {
  if (!Number.isFinite(v) || v === 0) return String(v);
  const e = Number(v.toExponential(n - 1).split('e')[1]);
  return e >= -5 && e < n ? v.toFixed(n - 1 - e) : v.toExponential(n - 1).replace('e+', 'e');
}

// Where the device lay still (a ball about each still period, sensor
// units; its rows set aside, no outliers), as magcal's text report names
// it.
function stillNote(f) {
  if (!f.dwell || !f.selection.dwell.length) return '';
  const balls = f.selection.dwell.map(
    ({ centre, radius }) => `within ${sig(radius, 2)} of (${centre.map((v) => sig(v, 4)).join(', ')})`,
  );
  return `still: set aside where the device lay still ${balls.join(', ')}`;
}

const vector = (prefix, v) =>
  `<span class="vec">${v.map((x, i) => `<span data-name="${prefix}${i}" data-value="${x}">${digits(x)}</span>`).join(' ')}</span>`;

function showPlanar(doc) {
  const f = doc.fit;
  const align = options('').align;
  const lim = info.limits.planar;
  $('figures').innerHTML = `<table class="figures">
    ${figure('turn axis', vector('a', f.axis), `unit vector; ${digits(f.axis_tilt_deg, 3)} deg from the up axis ${f.up}`)}
    ${figure('centre', vector('c', f.centre), 'sensor units: the hard iron in the plane; along the axis it is not observable')}
    ${figure('K', `<span class="mat">${f.matrix.map((row, r) => row.map((v, c) => `<span data-name="K${r}${c}" data-value="${v}">${digits(v)}</span>`).join(' ')).join('<br>')}</span>`, 'u = K (y − centre) on the unit circle; heading = angle(u) − zero')}
    ${figure('zero', f.zero_deg, align ? `deg: row ${html(align)}` : 'deg, arbitrary: set “heading 0 at” above')}
    ${figure('field in the plane', f.plane_strength, 'sensor units')}
    ${figure('fit error', f.fit_error, `robust sigma of |u| − 1; refused above ${lim.refuse_fit_error}`)}
    ${figure('flatness', f.flatness, `refused above ${lim.refuse_not_planar} (not turns about one axis); thickness ${digits(f.thickness, 3)} of the field in the plane`)}
    ${figure('coverage', `<span data-name="sectors" data-value="${f.sectors}">${f.sectors}</span> of ${lim.sectors} sectors of ${360 / lim.sectors} deg`, `refused below ${lim.min_sectors}`)}
    ${figure('columns', html(doc.columns))}
    ${doc.skipped ? figure('input', html(doc.skipped)) : ''}
    ${figure('samples', `${f.samples_used} used of ${doc.rows}: ${f.samples_dropped} dropped, ${f.screened} screened, ${f.rejected} rejected`)}
    ${figure('method', `planar (heading only), ${f.precision}, up ${f.up}`)}
    </table>`;
  $('c-summary').textContent = 'C: none, the C API (mag_cal.h) has no planar calibration';
  $('copy-c').title = 'The C API has no planar calibration.';
  $('send').title = "MotionCal's packet holds a 3-D calibration: a planar one is not sent.";
  $('report-command').textContent = 'magcal planar';
}

$('offer-fit').addEventListener('click', () => {
  $('mode').value = $('offer-fit').dataset.mode;
  syncMode();
  refit();
});

function warningText(doc) {
  if (!doc.warnings.length) return 'No warnings.';
  return doc.warnings.map((w) => `Warning: ${w.text}.`).join(' ');
}

// The norms of the used samples set the scale (at least 0.9 to 1.1); the
// others (a wild reading may be 100 fields away) sit clamped at the edges.
// A fit that marks no rows (planar): the middle 98 % of the norms set it.
function drawNorms(norms, classes) {
  const svg = $('norms');
  const finite = norms.filter(Number.isFinite);
  const sorted = [...finite].sort((a, b) => a - b);
  const scaled = classes
    ? norms.filter((v, i) => Number.isFinite(v) && classes[i] === 'used')
    : sorted.slice(Math.floor(sorted.length * 0.01), Math.ceil(sorted.length * 0.99));
  const lo = Math.min(0.9, ...scaled);
  const hi = Math.max(1.1, ...scaled);
  const x = (i) => (norms.length > 1 ? (i / (norms.length - 1)) * 790 + 5 : 400);
  const y = (v) => 215 - ((Math.min(Math.max(v, lo), hi) - lo) / (hi - lo)) * 210;
  const off = finite.filter((v) => v < lo || v > hi).length;
  const dots = norms
    .map((v, i) => (Number.isFinite(v) ? `<circle class="${classes ? classes[i].split(':')[0] : 'row'}" cx="${x(i).toFixed(1)}" cy="${y(v).toFixed(1)}" r="1.6"/>` : ''))
    .join('');
  svg.innerHTML =
    `<line class="unit" x1="0" x2="800" y1="${y(1)}" y2="${y(1)}"/>` +
    `<text x="4" y="12">${digits(hi, 3)}</text><text x="4" y="214">${digits(lo, 3)}</text>` +
    (off ? `<text x="796" y="12" text-anchor="end">${off} beyond the scale, at its edges</text>` : '') +
    dots;
}

// ---- outputs ------------------------------------------------------------------

$('download').addEventListener('click', () => {
  const blob = new Blob([state.result.json], { type: 'application/json' });
  const a = document.createElement('a');
  a.href = URL.createObjectURL(blob);
  a.download = 'calibration.json';
  a.click();
  URL.revokeObjectURL(a.href);
});
$('copy-c').addEventListener('click', () => navigator.clipboard.writeText(state.result.snippets.c));
$('copy-rust').addEventListener('click', () => navigator.clipboard.writeText(state.result.snippets.rust));
$('send').addEventListener('click', async () => {
  if (!port?.writable || !state.result?.packet) return;
  $('send').disabled = true;
  try {
    const writer = port.writable.getWriter();
    try {
      await writer.write(new Uint8Array(state.result.packet));
    } finally {
      writer.releaseLock();
    }
    state.sent += 1;
    $('send-status').textContent = "Sent MotionCal's 68-byte packet (units: 10 counts per uT).";
  } catch (err) {
    $('send-status').textContent = `Not sent: ${err.message}`;
  } finally {
    $('send').disabled = !port || !state.result?.packet;
  }
});

syncMode();
clearResult();
state.ready = true;
