// The jobs page: every job (a page of 50, newest first) with its thumbnail, state, progress,
// error, speed, ETA and priority; a state filter; the job actions. Polled every second; rows are
// updated in place (keyed by job id) so focus, a half-typed priority and open dialogs survive.

import { api, fetchImage } from './api.js';
import { actionButtons, updateActionButtons, priorityField, updatePriorityField } from './actions.js';
import { showBlob, releaseImage } from './images.js';
import {
  el, setText, poll, fmtInt, fmtError, fmtRate, fmtDuration, progress, JOB_STATES, FINAL_STATES,
} from './util.js';

const PER_PAGE = 50;
const THUMB_EVERY_MS = 3000;
// At most this many thumbnail downloads at once, so a long list cannot starve the pollers.
const THUMB_PARALLEL = 2;

export function mount(root, signal, query) {
  const state = query.get('state') || '';
  const page = Math.max(1, Number(query.get('page')) || 1);
  const go = (s, p) => {
    const q = new URLSearchParams();
    if (s) q.set('state', s);
    if (p > 1) q.set('page', String(p));
    location.hash = `#/jobs${q.size ? '?' + q : ''}`;
  };

  const filter = el('select', { id: 'state-filter', dataset: { testid: 'state-filter' } },
    el('option', { value: '' }, 'all'),
    JOB_STATES.map((s) => el('option', { value: s, selected: s === state }, s)));
  filter.addEventListener('change', () => go(filter.value, 1));

  const tbody = el('tbody');
  // Hidden until the first answer, so an empty table never flashes before "No jobs yet".
  const table = el('table', { class: 'jobs responsive', hidden: true, dataset: { testid: 'jobs-table' } },
    el('caption', { class: 'visually-hidden' }, 'Jobs, newest first'),
    el('thead', {}, el('tr', {},
      ['Preview', 'Job', 'State', 'Progress', 'Error', 'Samples/s', 'ETA', 'Priority', 'Actions']
        .map((h) => el('th', { scope: 'col' }, h)))),
    tbody);
  const count = el('p', { class: 'muted', dataset: { testid: 'jobs-count' } });
  const empty = el('p', { class: 'empty', hidden: true },
    state ? `No ${state} jobs. ` : 'No jobs yet. ', el('a', { href: '#/submit' }, 'Submit one'), '.');
  const prev = el('button', { type: 'button', onclick: () => go(state, page - 1) }, '← Newer');
  const next = el('button', { type: 'button', onclick: () => go(state, page + 1) }, 'Older →');
  const pageInfo = el('span');
  const pager = el('nav', { class: 'pager', 'aria-label': 'Pages of jobs', hidden: true }, prev, pageInfo, next);

  root.replaceChildren(el('section', { 'aria-labelledby': 'jobs-title' },
    el('div', { class: 'page-head' },
      el('h1', { id: 'jobs-title' }, 'Jobs'),
      el('div', { class: 'filters' }, el('label', { for: 'state-filter' }, 'State '), filter),
      el('a', { href: '#/submit', class: 'button primary' }, 'Submit a job')),
    count, el('div', { class: 'table-wrap' }, table), empty, pager));

  const rows = new Map(); // job id → row
  const thumbs = { active: 0 };

  let refresh = () => {};
  const update = async () => {
    const list = await api.jobs(state, page, PER_PAGE, signal);
    setText(count, `${list.total} job${list.total === 1 ? '' : 's'}${state ? ` ${state}` : ''}`);
    empty.hidden = list.jobs.length > 0;
    table.hidden = list.jobs.length === 0;
    const pages = Math.max(1, Math.ceil(list.total / PER_PAGE));
    pager.hidden = pages <= 1;
    prev.disabled = page <= 1;
    next.disabled = page >= pages;
    setText(pageInfo, `Page ${page} of ${pages}`);

    const seen = new Set();
    let before = null; // the row the next one must follow
    for (const job of list.jobs) {
      seen.add(job.id);
      let row = rows.get(job.id);
      if (!row) {
        row = makeRow(job, () => refresh());
        rows.set(job.id, row);
      }
      row.ref.job = job;
      fillRow(row, job);
      // Move a row only when out of place: moving a node takes the focus away from it.
      const wanted = before ? before.nextElementSibling : tbody.firstElementChild;
      if (wanted !== row) tbody.insertBefore(row, wanted);
      before = row;
      maybeThumb(row, thumbs, signal);
    }
    for (const [id, row] of rows) {
      if (!seen.has(id)) {
        releaseImage(row.querySelector('img'));
        row.remove();
        rows.delete(id);
      }
    }
  };
  refresh = poll(update, 1000, signal);
  signal.addEventListener('abort', () => {
    for (const row of rows.values()) releaseImage(row.querySelector('img'));
  });
}

function makeRow(job, refresh) {
  // The freshest JobView of this row, replaced by every poll; the buttons read it when clicked.
  const ref = { job };
  const getJob = () => ref.job;
  const after = () => refresh();
  // One wrapper per cell: on a phone each cell is a two-column grid (its label, its content).
  const cell = (label, ...children) => el('td', { dataset: { label } }, el('div', { class: 'cell' }, ...children));
  const thumb = el('img', { class: 'thumb', alt: '', width: 64, height: 64, dataset: { testid: 'thumb' } });
  const bar = el('progress', { max: 1, value: 0, 'aria-label': 'Progress' });
  const priority = priorityField(getJob, after, `priority-${job.id}`);
  const row = el('tr', { dataset: { jobId: job.id, testid: 'job-row' } },
    cell('Preview', el('div', { class: 'thumb-box' }, thumb)),
    el('th', { scope: 'row', dataset: { label: 'Job' } }, el('div', { class: 'cell' },
      el('a', { href: `#/jobs/${job.id}`, class: 'job-name', dataset: { testid: 'job-link' } }, job.name),
      el('small', { class: 'muted' }, `${job.settings.width}×${job.settings.height}, ${job.settings.spp} spp`))),
    cell('State', el('span', { class: 'badge', dataset: { testid: 'job-state' } })),
    cell('Progress', bar, el('small', { class: 'progress-text', dataset: { testid: 'job-progress' } })),
    cell('Error', el('span', { dataset: { testid: 'job-error' } })),
    cell('Samples/s', el('span', { dataset: { testid: 'job-rate' } })),
    cell('ETA', el('span', { dataset: { testid: 'job-eta' } })),
    cell('Priority', el('label', { for: priority.id, class: 'visually-hidden' }, `Priority of ${job.name}`), priority),
    cell('Actions', actionButtons(getJob, after)));
  row.ref = ref;
  row.thumb = { etag: null, samplesDone: -1, state: null, at: 0 };
  return row;
}

function fillRow(row, job) {
  row.dataset.state = job.state;
  const q = (id) => row.querySelector(`[data-testid="${id}"]`);
  const badge = q('job-state');
  setText(badge, job.state);
  badge.className = `badge state-${job.state}`;
  const bar = row.querySelector('progress');
  const p = progress(job);
  if (Number(bar.value) !== p) bar.value = p;
  const frames = job.frames_total ? `, ${fmtInt(job.frames_done)} / ${fmtInt(job.frames_total)} frames` : '';
  setText(q('job-progress'), `${fmtInt(job.samples_done)} / ${fmtInt(job.samples_planned)} (${(p * 100).toFixed(0)} %)${frames}`);
  setText(q('job-error'), fmtError(job.relative_error));
  setText(q('job-rate'), job.state === 'running' ? fmtRate(job.samples_per_second) : '–');
  setText(q('job-eta'), fmtDuration(job.eta_seconds));
  updatePriorityField(q('priority'), job);
  updateActionButtons(row.querySelector('.actions'), job);
}

// Refreshes a row's thumbnail when its samples changed, at most every few seconds (and once more
// when the job ends, so the list shows final images).
function maybeThumb(row, thumbs, signal) {
  const job = row.ref.job;
  const t = row.thumb;
  if (job.samples_done === 0 || job.samples_done === t.samplesDone || t.busy) return;
  const ended = FINAL_STATES.has(job.state) && t.state !== job.state;
  if (!ended && Date.now() - t.at < THUMB_EVERY_MS) return;
  if (thumbs.active >= THUMB_PARALLEL) return;
  thumbs.active++;
  t.busy = true;
  const samples = job.samples_done;
  fetchImage(`/jobs/${encodeURIComponent(job.id)}/preview.png`, { etag: t.etag, signal })
    .then(async (r) => {
      if (r.changed && !signal.aborted) await showBlob(row.querySelector('img'), r.blob);
      t.etag = r.etag;
      t.samplesDone = samples;
      t.state = job.state;
    })
    .catch(() => {}) // a thumbnail is decoration; the next poll tries again
    .finally(() => {
      thumbs.active--;
      t.busy = false;
      t.at = Date.now();
    });
}
