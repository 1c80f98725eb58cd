// The job page: the live progress image (tone-mapped, or a heat map of samples or noise per
// pixel) with the tile overlay, the job's numbers, actions and settings, downloads, and the
// convergence and throughput charts. A frame job adds its frame strip and player (frames.js):
// the image, overlay and downloads are then those of the frame selected.
//
// Polling: the JobView about three times a second while the job can still change (every five
// seconds once it is final); the preview only when the merged samples (or the view) changed
// since the image on screen; the convergence history every second.

import { api, fetchImage, download, ApiError } from './api.js';
import { actionButtons, updateActionButtons, priorityField, updatePriorityField } from './actions.js';
import { showBlob, releaseImage } from './images.js';
import { errorChart, rateChart } from './charts.js';
import { frameStrip } from './frames.js';
import {
  el, setText, poll, showError, fmtInt, fmtError, fmtRate, fmtDuration, fmtTime, progress,
  FINAL_STATES,
} from './util.js';

const LIVE_MS = 330;
const FINAL_MS = 5000;

// Previews of a frame job's frames kept for the player, at most this many (oldest out).
const FRAME_CACHE = 240;

const VIEWS = [
  { value: 'image', label: 'Current image' },
  { value: 'samples', label: 'Samples per pixel' },
  { value: 'noise', label: 'Noise (relative std. error)' },
];

export function mount(root, pageSignal, _query, id) {
  let job = null;
  // Stops this page's pollers when the page is left, or when the job turns out to be gone.
  const stop = new AbortController();
  pageSignal.addEventListener('abort', () => stop.abort());
  const signal = stop.signal;
  const enc = encodeURIComponent(id);
  // A frame job's strip (null for a still job), and the frame it shows.
  let strip = null;
  const frame = () => (strip ? strip.selected() : null);
  const frameQuery = (sep) => (frame() === null ? '' : `${sep}frame=${frame()}`);

  // ---- preview controls
  const viewBox = el('fieldset', { class: 'views' }, el('legend', {}, 'Show'),
    VIEWS.map((v) => el('label', {},
      el('input', { type: 'radio', name: 'view', value: v.value, checked: v.value === 'image', dataset: { testid: `view-${v.value}` } }),
      ` ${v.label}`)));
  const exposure = el('input', { type: 'range', id: 'exposure', min: -8, max: 8, step: 0.5, value: 0, dataset: { testid: 'exposure' } });
  const exposureOut = el('output', { for: 'exposure', id: 'exposure-value' }, '0 EV');
  const overlayToggle = el('input', { type: 'checkbox', id: 'overlay-toggle', checked: true, dataset: { testid: 'overlay-toggle' } });
  const controls = el('div', { class: 'preview-controls' },
    viewBox,
    el('div', { class: 'exposure' }, el('label', { for: 'exposure' }, 'Exposure'), exposure, exposureOut),
    el('div', {}, overlayToggle, el('label', { for: 'overlay-toggle' }, ' Tile overlay')));

  // ---- the image, the tile overlay on top of it, the heat-map legend under it
  const img = el('img', { id: 'preview', alt: 'Current image of the job', dataset: { testid: 'preview-image' } });
  const overlay = document.createElementNS('http://www.w3.org/2000/svg', 'svg');
  overlay.classList.add('overlay');
  overlay.setAttribute('aria-hidden', 'true');
  overlay.setAttribute('preserveAspectRatio', 'none');
  const stage = el('div', { class: 'stage', dataset: { testid: 'preview-stage' } }, img, overlay);
  const legendMin = el('span', { dataset: { testid: 'legend-min' } });
  const legendMax = el('span', { dataset: { testid: 'legend-max' } });
  const legendNote = el('span', { class: 'muted' });
  const legend = el('div', { class: 'legend', hidden: true, dataset: { testid: 'legend' } },
    legendMin, el('span', { class: 'ramp', 'aria-hidden': 'true' }), legendMax, legendNote);
  const caption = el('figcaption', {}, legend, el('span', { class: 'muted', dataset: { testid: 'preview-caption' } }));

  // ---- numbers, actions, settings, downloads, charts
  const title = el('h1', { id: 'job-title', dataset: { testid: 'job-title' } }, 'Job');
  const badge = el('span', { class: 'badge', id: 'job-page-state', dataset: { testid: 'job-state' } });
  const headActions = el('div', { class: 'head-actions' });
  const stats = el('dl', { class: 'stats', dataset: { testid: 'job-stats' } });
  const settings = el('dl', { class: 'settings', dataset: { testid: 'job-settings' } });
  const message = el('p', { class: 'message', hidden: true, dataset: { testid: 'job-message' } });
  // What the scene loader ignored, as the server found it at submission (it never changes).
  const warnings = el('section', { class: 'warnings', hidden: true, 'aria-labelledby': 'warnings-title', dataset: { testid: 'job-warnings' } });
  const errorBox = el('div', { class: 'chart', dataset: { testid: 'error-chart', points: '0' } });
  // A frame job's charts are the selected frame's history: the heading says which.
  const chartsFrame = el('span', { class: 'muted', dataset: { testid: 'charts-frame' } });
  const errorSummary = el('p', { class: 'muted chart-summary' });
  const rateBox = el('div', { class: 'chart', dataset: { testid: 'rate-chart', points: '0' } });
  const rateSummary = el('p', { class: 'muted chart-summary' });
  const dl = (label, path, file, testid) => el('button', {
    type: 'button', dataset: { testid },
    onclick: () => download(path(), file()).catch(showError),
  }, label);
  const base = () => (job ? job.name.replace(/[^\w.-]+/g, '_').replace(/\.(gltf|glb)$/i, '') : id);
  const frameName = () => (frame() === null ? '' : `-${String(frame()).padStart(4, '0')}`);
  const downloads = el('div', { class: 'downloads', role: 'group', 'aria-label': 'Downloads' },
    dl('EXR', () => `/jobs/${enc}/image.exr${frameQuery('?')}`, () => `${base()}${frameName()}.exr`, 'download-exr'),
    dl('EXR + variance, samples', () => `/jobs/${enc}/image.exr?extra=true${frameQuery('&')}`, () => `${base()}${frameName()}-extra.exr`, 'download-exr-extra'),
    dl('PNG', () => `/jobs/${enc}/preview.png?exposure=${exposure.value}${frameQuery('&')}`, () => `${base()}${frameName()}.png`, 'download-png'));
  // A frame job's: every rendered frame, and the complete ones animated.
  const frameDownloads = () => [
    dl('All frames (tar of EXRs)', () => `/jobs/${enc}/frames.tar`, () => `${base()}-frames.tar`, 'download-frames-tar'),
    dl('Animated PNG', () => `/jobs/${enc}/preview.apng?exposure=${exposure.value}`, () => `${base()}.apng`, 'download-apng'),
  ];

  const previewSection = el('section', { class: 'preview-section', 'aria-label': 'Progress image' },
    el('figure', { class: 'preview' }, stage, caption), controls);
  root.replaceChildren(el('article', { class: 'job', 'aria-labelledby': 'job-title' },
    el('div', { class: 'page-head' }, el('p', { class: 'crumb' }, el('a', { href: '#/jobs' }, '← Jobs')), title, badge, headActions),
    message,
    warnings,
    el('div', { class: 'job-grid' },
      previewSection,
      el('div', { class: 'side' },
        el('section', { 'aria-labelledby': 'progress-title' }, el('h2', { id: 'progress-title' }, 'Progress'), stats),
        el('section', { 'aria-labelledby': 'downloads-title' }, el('h2', { id: 'downloads-title' }, 'Download'), downloads),
        el('section', { 'aria-labelledby': 'settings-title' }, el('h2', { id: 'settings-title' }, 'Settings'), settings))),
    el('section', { class: 'charts', 'aria-labelledby': 'charts-title' },
      el('h2', { id: 'charts-title' }, 'Convergence', chartsFrame),
      el('div', { class: 'chart-grid' },
        el('figure', {}, el('figcaption', {}, 'Estimated relative error against time (log–log), with the 1/√t slope'), errorBox, errorSummary),
        el('figure', {}, el('figcaption', {}, 'Samples per second'), rateBox, rateSummary)))));

  const charts = [errorChart(errorBox, errorSummary), rateChart(rateBox, rateSummary)];
  signal.addEventListener('abort', () => {
    charts.forEach((c) => c.destroy());
    strip?.destroy();
    releaseImage(img);
  });

  // ---- state of the preview on screen
  const shown = { key: null, etag: null, samples: -1 };
  // A frame job's previews by key and frame, with the samples they show: the player shows a
  // frame it has seen at once, without a request.
  const frameCache = new Map();
  const view = () => viewBox.querySelector('input:checked').value;
  const previewKey = () => (view() === 'image' ? `image@${exposure.value}` : view()) + frameQuery('#');
  // The merged samples of what the preview shows: the job's, or the selected frame's.
  const shownFrame = () => (frame() === null ? null : (job.frames || []).find((f) => f.frame === frame()));
  const samplesShown = () => (frame() === null ? job.samples_done : shownFrame()?.samples_done ?? 0);

  async function show(blob, headers, etag) {
    await showBlob(img, blob);
    img.dataset.etag = etag || '';
    img.dataset.view = view();
    img.dataset.frame = frame() === null ? '' : String(frame());
    img.alt = `${VIEWS.find((v) => v.value === view()).label} of ${job.name}${frame() === null ? '' : `, frame ${frame()}`}${view() === 'image' ? '' : ' (heat map)'}`;
    showLegend(headers);
  }

  async function updatePreview() {
    if (!job) return;
    const samples = samplesShown();
    if (samples === 0) return;
    const key = previewKey();
    // Same image as on screen: nothing merged since, same view, exposure and frame.
    if (key === shown.key && samples === shown.samples) return;
    const kept = frameCache.get(key);
    if (kept && kept.samples === samples) {
      await show(kept.blob, kept.headers, kept.etag);
      Object.assign(shown, { key, etag: kept.etag, samples });
      return;
    }
    const q = new URLSearchParams({ view: view() });
    if (view() === 'image') q.set('exposure', exposure.value);
    if (frame() !== null) q.set('frame', frame());
    const r = await fetchImage(`/jobs/${enc}/preview.png?${q}`, {
      etag: key === shown.key ? shown.etag : null, signal,
    });
    // Kept even when the player has moved on meanwhile: the next round shows it at once.
    if (r.changed && strip) {
      frameCache.delete(key);
      frameCache.set(key, { samples, blob: r.blob, headers: r.headers, etag: r.etag });
      if (frameCache.size > FRAME_CACHE) frameCache.delete(frameCache.keys().next().value);
    }
    if (key !== previewKey()) return; // the view or frame changed meanwhile; the next poll fetches it
    if (r.changed) await show(r.blob, r.headers, r.etag);
    shown.key = key;
    shown.etag = r.etag;
    shown.samples = samples;
  }

  function showLegend(headers) {
    const v = view();
    const lo = Number(headers.get('pathfarm-scale-min'));
    const hi = Number(headers.get('pathfarm-scale-max'));
    const has = v !== 'image' && headers.has('pathfarm-scale-min') && headers.has('pathfarm-scale-max');
    legend.hidden = !has;
    if (!has) return;
    if (v === 'samples') {
      legendMin.textContent = `${fmtInt(lo)} spp`;
      legendMax.textContent = `${fmtInt(hi)} spp`;
      legendNote.textContent = ' linear';
    } else {
      legendMin.textContent = fmtError(lo);
      legendMax.textContent = fmtError(hi);
      legendNote.textContent = ' logarithmic';
    }
  }

  const refreshPreview = () => updatePreview().catch(showError);
  viewBox.addEventListener('change', () => {
    exposure.disabled = view() !== 'image';
    refreshPreview();
  });
  exposure.addEventListener('input', () => {
    exposureOut.value = `${exposure.value > 0 ? '+' : ''}${exposure.value} EV`;
  });
  exposure.addEventListener('change', refreshPreview);
  overlayToggle.addEventListener('change', () => {
    overlay.style.display = overlayToggle.checked ? '' : 'none';
  });

  let refresh = () => {};
  const after = (result) => {
    if (result === 'deleted') location.hash = '#/jobs';
    else refresh();
  };

  function firstFill() {
    setText(title, job.name);
    document.title = `${job.name} · pathfarm`;
    img.alt = `Current image of ${job.name}`;
    stage.style.aspectRatio = `${job.settings.width} / ${job.settings.height}`;
    // Small renders are scaled up with crisp pixels, large ones scaled down to fit.
    stage.style.maxWidth = `${Math.max(job.settings.width, 512)}px`;
    overlay.setAttribute('viewBox', `0 0 ${job.settings.width} ${job.settings.height}`);
    const priority = priorityField(() => job, after, 'job-priority');
    headActions.append(
      el('span', { class: 'priority-box' }, el('label', { for: 'job-priority' }, 'Priority '), priority),
      actionButtons(() => job, after));
    fillSettings(settings, job);
    fillWarnings(warnings, job);
    if (job.frames_total) {
      strip = frameStrip(() => {
        if (job.tiles) drawTiles(overlay, job, frame());
        fillCaption();
        refreshPreview();
        // While the player runs, the charts stay with their poll (once a second) rather than
        // asking for every frame it steps through.
        if (!strip.playing()) refreshCharts();
      });
      previewSection.append(strip.element);
      downloads.append(...frameDownloads());
    }
  }

  function fillCaption() {
    const f = shownFrame();
    const perPixel = f ? f.samples_per_pixel : job.samples_done / (job.settings.width * job.settings.height);
    setText(caption.lastChild, samplesShown() === 0
      ? `No samples${f ? ` in frame ${f.frame}` : ''} yet: the image appears after the first pass.`
      : `${f ? `Frame ${f.frame}: ` : ''}${job.settings.width}×${job.settings.height}, ${fmtInt(perPixel)} samples per pixel${f ? `, error ${fmtError(f.relative_error)}` : ' on average'}`);
  }

  function fill() {
    setText(badge, job.state);
    badge.className = `badge state-${job.state}`;
    updateActionButtons(headActions.querySelector('.actions'), job);
    updatePriorityField(headActions.querySelector('#job-priority'), job);
    message.hidden = !job.message;
    setText(message, job.message || '');
    fillStats(stats, job);
    if (strip) strip.update(job);
    if (job.tiles) drawTiles(overlay, job, frame());
    fillCaption();
  }

  const update = async () => {
    let next;
    try {
      next = await api.job(id, signal);
    } catch (e) {
      if (e instanceof ApiError && e.status === 404) {
        root.replaceChildren(el('section', {}, el('h1', {}, 'No such job'),
          el('p', { dataset: { testid: 'job-missing' } }, `Job ${id} does not exist (any more). `, el('a', { href: '#/jobs' }, 'All jobs'))));
        stop.abort();
        return;
      }
      throw e;
    }
    const first = job === null;
    job = next;
    if (first) firstFill();
    fill();
    await updatePreview();
  };
  refresh = poll(update, () => (job && FINAL_STATES.has(job.state) ? FINAL_MS : LIVE_MS), signal);

  // The convergence history (a frame job's: the selected frame's); once the job is final one
  // more fetch shows its last points, and one more whenever another frame is selected.
  let finalFetched = null;
  const refreshCharts = poll(async () => {
    const shown = frame();
    if (!job || finalFetched === String(shown)) return;
    const final = FINAL_STATES.has(job.state);
    let points = [];
    try {
      points = (await api.convergence(id, signal, shown)).points;
    } catch (e) {
      // A server without the history (or a job just deleted) draws empty charts.
      if (!(e instanceof ApiError && e.status === 404)) throw e;
    }
    // A frame selected while the answer was on its way: the next fetch draws it.
    if (String(frame()) !== String(shown)) return;
    errorBox.dataset.frame = shown === null ? '' : String(shown);
    setText(chartsFrame, shown === null ? '' : ` · frame ${shown}`);
    charts.forEach((c) => c.update(points, String(shown)));
    finalFetched = final ? String(shown) : null;
  }, 1000, signal);
}

function fillStats(dl, job) {
  const elapsed = job.started_at_ms ? ((job.finished_at_ms || Date.now()) - job.started_at_ms) / 1000 : null;
  const p = progress(job);
  const rows = [
    ['Samples', 'samples', `${fmtInt(job.samples_done)} / ${fmtInt(job.samples_planned)} (${(p * 100).toFixed(1)} %)`],
    [job.frames_total == null ? 'Relative error' : 'Relative error (worst frame)', 'error', fmtError(job.relative_error)],
    ['Samples per second', 'rate', fmtRate(job.samples_per_second)],
    ['ETA', 'eta', fmtDuration(job.eta_seconds)],
    ['Elapsed', 'elapsed', fmtDuration(elapsed)],
    ['Leased tasks', 'leased', String(job.leased_tasks)],
  ];
  if (job.frames_total) rows.splice(1, 0, ['Frames complete', 'frames', `${fmtInt(job.frames_done)} / ${fmtInt(job.frames_total)}`]);
  if (!dl.firstChild) {
    const bar = el('progress', { max: 1, value: 0, 'aria-label': 'Progress', dataset: { testid: 'job-progress-bar' } });
    for (const [label, key] of rows) {
      dl.append(el('div', {}, el('dt', {}, label), el('dd', { dataset: { testid: `stat-${key}` } })));
    }
    dl.append(el('div', { class: 'bar' }, bar));
  }
  for (const [, key, value] of rows) setText(dl.querySelector(`[data-testid="stat-${key}"]`), value);
  dl.querySelector('progress').value = p;
}

// The environment light as the render flags give it: a colour or an image (by its hash), its
// strength and rotation.
export function environmentText(e) {
  if (!e) return 'none';
  const source = e.radiance
    ? `uniform ${e.radiance.map((c) => String(c)).join(', ')}`
    : `image ${String(e.image).slice(0, 12)}…`;
  const parts = [source];
  if (e.strength !== 1) parts.push(`strength ${e.strength}`);
  if (e.rotation_degrees) parts.push(`rotated ${e.rotation_degrees}°`);
  return parts.join(', ');
}

function fillWarnings(section, job) {
  const list = job.warnings || [];
  section.hidden = list.length === 0;
  section.replaceChildren(
    el('h2', { id: 'warnings-title' }, `Scene warnings (${list.length})`),
    el('p', { class: 'muted' }, 'Features of the scene the renderer ignored:'),
    el('ul', {}, list.map((w) => el('li', { dataset: { testid: 'job-warning' } }, w))));
}

function fillSettings(dl, job) {
  const s = job.settings;
  const rows = [
    ['Resolution', `${s.width} × ${s.height}`],
    ['Samples per pixel', String(s.spp)],
    ['Seed', String(s.seed)],
    ['Direct lighting', s.direct],
    ['Sampler', s.sampler],
    ['Russian roulette', String(s.rr)],
    ['Max depth', s.max_depth ?? 'unlimited'],
    ['Tile size', String(s.tile_size)],
    ['Camera', s.camera ?? 'first in the scene'],
    ['Noise target', s.noise_target ? fmtError(s.noise_target) : '–'],
    ['Time limit', s.time_limit_s ? fmtDuration(s.time_limit_s) : '–'],
    ...(s.frames ? [['Frames', `${s.frames} at ${s.fps ?? 24} fps, ${s.frame_order ?? 'interleaved'}`]] : []),
    ['Environment', el('span', { title: s.environment?.image ?? '', dataset: { testid: 'job-environment' } }, environmentText(s.environment))],
    ['Scene', el('code', { title: job.scene_hash }, job.scene_hash.slice(0, 12) + '…')],
    ['Submitted', fmtTime(job.created_at_ms)],
    ['Started', fmtTime(job.started_at_ms)],
  ];
  dl.replaceChildren(...rows.map(([k, v]) => el('div', {}, el('dt', {}, k), el('dd', {}, v))));
}

// Per tile, over the image: its outline and a bar along its bottom edge filled in proportion to
// its merged samples, so the overlay shows progress without hiding the picture (or the heat map)
// underneath. Finished tiles draw nothing. A frame job's tiles are those of `frame`, the frame shown.
function drawTiles(svg, job, frame) {
  const NS = 'http://www.w3.org/2000/svg';
  const make = (tag, cls) => {
    const n = document.createElementNS(NS, tag);
    if (cls) n.setAttribute('class', cls);
    return n;
  };
  const set = (node, attrs) => {
    for (const [k, v] of Object.entries(attrs)) {
      if (node.getAttribute(k) !== String(v)) node.setAttribute(k, String(v));
    }
  };
  const spp = job.settings.spp;
  const tiles = job.tiles.filter((t) => t.frame == null || t.frame === frame);
  tiles.forEach((t, i) => {
    let g = svg.children[i];
    if (!g) {
      g = make('g');
      g.append(make('title'), make('rect', 'tile-outline'), make('rect', 'tile-bar-bg'), make('rect', 'tile-bar'));
      svg.append(g);
    }
    const done = Math.min(1, t.samples_per_pixel / spp);
    const h = Math.max(1, Math.min(t.height, Math.round(t.height * 0.06)));
    const bottom = t.y0 + t.height - h;
    set(g, { class: done >= 1 ? 'tile done' : t.samples_per_pixel > 0 ? 'tile partial' : 'tile empty' });
    set(g.children[1], { x: t.x0, y: t.y0, width: t.width, height: t.height });
    set(g.children[2], { x: t.x0, y: bottom, width: t.width, height: h });
    set(g.children[3], { x: t.x0, y: bottom, width: (t.width * done).toFixed(2), height: h });
    g.firstChild.textContent = `tile at ${t.x0},${t.y0}: ${t.samples_per_pixel} / ${spp} spp`;
  });
  while (svg.children.length > tiles.length) svg.lastChild.remove();
}
