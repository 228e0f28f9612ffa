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
  result: null, // the core's last fit document
  progress: null, // the collector's last progress
  raw: [], // samples received over serial
  sent: 0, // packets written to the board
};
state.core = core;
window.magcal = state;

for (const m of info.methods) $('method').append(new Option(m, m));
buildCells();

function options(name) {
  return {
    name,
    precision: $('precision').value,
    method: $('method').value,
    plain: $('plain').checked,
    columns: $('columns').value.trim(),
  };
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
  rawView.setPoints(doc.raw ?? [], doc.classes, doc.fit?.hard_iron, doc.fit?.field_strength);
  showResult(doc, lastFile.name);
}

$('file').addEventListener('change', (e) => {
  if (e.target.files.length) openFile(e.target.files[0]);
});
document.addEventListener('dragover', (e) => e.preventDefault());
document.addEventListener('drop', (e) => {
  e.preventDefault();
  if (e.dataTransfer.files.length) openFile(e.dataTransfer.files[0]);
});
for (const id of ['precision', 'method', 'plain', 'columns']) {
  $(id).addEventListener('change', () => (state.source === 'serial' ? fitLive(true) : fitFile()));
}

// ---- a board over WebSerial -----------------------------------------------

let port = null;
let reader = null;
let piping = null; // the current pipe from the port into the line decoder
let session = 0; // one per connection: a stale read loop must not touch a new one
let acceptedSinceFit = 0;

// What a failed call of the core means for the page.
function coreFailed(err) {
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
  state.result = null;
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
    rawView.setPoints(state.raw, null, state.result?.fit?.hard_iron, state.result?.fit?.field_strength);
    // Refit as the collection grows, once it is ready.
    if (p.ready && acceptedSinceFit >= 25) fitLive(false);
  });
}

function fitLive(force) {
  if (state.source !== 'serial' || !state.progress) return;
  if (!force && !state.progress.ready) return;
  acceptedSinceFit = 0;
  let doc;
  try {
    doc = core.liveFit(options('serial'));
  } catch (err) {
    coreFailed(err);
    return;
  }
  if (doc.status === 'ok' || force) showResult(doc, 'serial');
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
      ? `; restarts: ${p.refused.restarted} (a wild first reading, the board lying still at first, or a long run of readings far from those kept; ${p.discarded} samples discarded)`
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

function showResult(doc, name) {
  state.result = doc;
  $('result').hidden = false;
  const ok = doc.status === 'ok';
  $('verdict').textContent = ok
    ? `Calibrated: ${name}`
    : doc.status === 'refused'
      ? `Refused: ${name}`
      : `Not read: ${name}`;
  $('verdict').className = ok ? 'good' : 'bad';
  $('message').textContent = ok ? warningText(doc) : doc.message;
  $('message').className = `message ${ok ? (doc.warnings.length ? 'warn' : '') : 'bad'}`;
  for (const id of ['download', 'copy-c', 'copy-rust']) $(id).disabled = !ok;
  $('send').disabled = !ok || !port;
  if (!ok) {
    $('figures').innerHTML = doc.columns
      ? `<p>${doc.rows} rows from ${html(doc.columns)}</p>${doc.skipped ? `<p data-name="input">${html(doc.skipped)}</p>` : ''}`
      : '';
    $('norms').innerHTML = '';
    calView.setPoints([], null, null, null);
    $('report').textContent = '';
    setStatus(doc.message, 'bad');
    return;
  }
  const f = doc.fit;
  const q = f.quality;
  const w = f.soft_iron;
  $('figures').innerHTML = `<table class="figures">
    ${figure('hard iron b', `<span class="vec">${f.hard_iron.map((v, i) => `<span data-name="b${i}" data-value="${v}">${digits(v)}</span>`).join(' ')}</span>`, 'sensor units')}
    ${figure('soft iron W', `<span class="mat">${w.map((row, r) => row.map((v, c) => `<span data-name="W${r}${c}" data-value="${v}">${digits(v)}</span>`).join(' ')).join('<br>')}</span>`, 'W (y − b) on the unit sphere')}
    ${figure('field strength', f.field_strength, 'sensor units')}
    ${figure('radial RMS', q.radial_rms, 'of the field')}
    ${figure('fit error', q.fit_error, 'robust sigma; warned above 0.05, refused above 0.2')}
    ${figure('coverage', q.coverage, 'refused below 0.05; full sphere about 0.33')}
    ${figure('flatness', q.flatness, 'refused below 0.03')}
    ${figure('distortion', q.distortion, 'condition number of M; refused above 16')}
    ${figure('lack of fit', q.lack_of_fit, 'systematic misfit; refused above 0.01 when significant')}
    ${figure('outlier share', q.outlier_share, 'refused above 0.25')}
    ${figure('columns', html(doc.columns))}
    ${doc.skipped ? figure('input', html(doc.skipped)) : ''}
    ${figure('samples', `${f.samples_used} used of ${doc.rows}: ${f.samples_dropped} dropped, ${f.screened} screened, ${f.rejected} rejected`)}
    ${figure('method', `${f.method} (LS ${f.ls}), ${f.precision}, ${f.robust ? 'robust' : 'plain'}; ${digits(f.timing_us / 1000, 3)} ms`)}
    </table>`;
  $('snippet-c').textContent = doc.snippets.c;
  $('snippet-rust').textContent = doc.snippets.rust;
  $('report').textContent = doc.text;
  calView.setPoints(doc.calibrated, doc.classes, [0, 0, 0], 1);
  drawNorms(doc.norms, doc.classes);
  setStatus(state.source === 'serial' ? 'Calibrated from the board: keep turning to refine, or send it.' : 'Calibrated.', 'good');
}

function warningText(doc) {
  if (!doc.warnings.length) return 'No warnings.';
  return doc.warnings.map((w) => `Warning: ${w.text}.`).join(' ');
}

// The norms of the used samples set the scale (at least 0.9 to 1.1); the
// others (a wild reading may be 100 fields away) sit clamped at the edges.
function drawNorms(norms, classes) {
  const svg = $('norms');
  const used = norms.filter((v, i) => Number.isFinite(v) && classes[i] === 'used');
  const lo = Math.min(0.9, ...used);
  const hi = Math.max(1.1, ...used);
  const x = (i) => (norms.length > 1 ? (i / (norms.length - 1)) * 790 + 5 : 400);
  const y = (v) => 215 - ((Math.min(Math.max(v, lo), hi) - lo) / (hi - lo)) * 210;
  const off = norms.filter((v) => Number.isFinite(v) && (v < lo || v > hi)).length;
  const dots = norms
    .map((v, i) => (Number.isFinite(v) ? `<circle class="${classes[i].split(':')[0]}" cx="${x(i).toFixed(1)}" cy="${y(v).toFixed(1)}" r="1.6"/>` : ''))
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
  if (!port?.writable || state.result?.status !== 'ok') return;
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
    $('send').disabled = !port;
  }
});

state.ready = true;
