// The workers page: every worker with its state (lost ones flagged), host, threads, current task,
// speed and last heartbeat, a page of 100 at a time (newest first), with a pager so that every
// worker can be reached however many there are. Pages follow the server's cursors, kept in the
// address (`at`: the cursor of each page up to this one), so that workers registering or being
// collected while one pages through move no worker past the pager. Polled every two seconds; rows
// updated in place by worker id.

import { api } from './api.js';
import { el, setText, poll, fmtInt, fmtRate, fmtAgo, fmtTime } from './util.js';

const PER_PAGE = 100;

export function mount(root, signal, query) {
  const trail = query ? query.getAll('at').filter((c) => c) : [];
  const page = trail.length + 1;
  let next = null;
  const go = (cursors) => {
    const q = new URLSearchParams();
    for (const c of cursors) q.append('at', c);
    location.hash = cursors.length ? `#/workers?${q}` : '#/workers';
  };
  const tbody = el('tbody');
  const table = el('table', { class: 'workers responsive', hidden: true, dataset: { testid: 'workers-table' } },
    el('caption', { class: 'visually-hidden' }, 'Workers: newest first'),
    el('thead', {}, el('tr', {},
      ['Worker', 'State', 'Host', 'Threads', 'Current task', 'Samples/s', 'Samples', 'Last heartbeat', 'Version']
        .map((h) => el('th', { scope: 'col' }, h)))),
    tbody);
  const summary = el('p', { class: 'muted', dataset: { testid: 'workers-summary' } });
  const empty = el('p', { class: 'empty', hidden: true },
    'No worker has registered yet. Start one with ', el('code', {}, 'pathfarm worker --server URL'), '.');
  const prev = el('button', { type: 'button', onclick: () => go(trail.slice(0, -1)) }, '← Previous');
  const nextButton = el('button', { type: 'button', onclick: () => next && go([...trail, next]) }, 'Next →');
  const pageInfo = el('span', { dataset: { testid: 'workers-page' } });
  const pager = el('nav', { class: 'pager', 'aria-label': 'Pages of workers', hidden: true, dataset: { testid: 'workers-pager' } },
    prev, pageInfo, nextButton);
  root.replaceChildren(el('section', { 'aria-labelledby': 'workers-title' },
    el('div', { class: 'page-head' }, el('h1', { id: 'workers-title' }, 'Workers')),
    summary, el('div', { class: 'table-wrap' }, table), empty, pager));

  const rows = new Map();
  poll(async () => {
    const list = await api.workers(trail[trail.length - 1] || null, PER_PAGE, signal);
    const { workers, total } = list;
    next = list.next || null;
    const by = (s) => workers.filter((w) => w.state === s).length;
    const pages = Math.max(1, Math.ceil(total / PER_PAGE));
    // The states are counted on the page shown: with more than one page, say so.
    setText(summary, `${total} worker${total === 1 ? '' : 's'}${pages > 1 ? '; on this page' : ''}: ${by('busy')} busy, ${by('idle')} idle, ${by('lost')} lost, ${by('offline')} offline`);
    pager.hidden = pages <= 1 && page <= 1;
    prev.disabled = page <= 1;
    nextButton.disabled = !next;
    setText(pageInfo, `Page ${page} of ${Math.max(page, pages)}`);
    empty.hidden = total > 0;
    table.hidden = workers.length === 0;
    const seen = new Set();
    let before = null;
    for (const w of workers) {
      seen.add(w.id);
      let row = rows.get(w.id);
      if (!row) {
        row = makeRow(w);
        rows.set(w.id, row);
      }
      fillRow(row, w);
      const wanted = before ? before.nextElementSibling : tbody.firstElementChild;
      if (wanted !== row) tbody.insertBefore(row, wanted);
      before = row;
    }
    for (const [id, row] of rows) {
      if (!seen.has(id)) {
        row.remove();
        rows.delete(id);
      }
    }
  }, 2000, signal);
}

function makeRow(w) {
  const cell = (label, testid) => el('td', { dataset: { label, testid } });
  return el('tr', { dataset: { workerId: w.id, testid: 'worker-row' } },
    el('th', { scope: 'row', dataset: { label: 'Worker', testid: 'worker-name' } }, w.name),
    el('td', { dataset: { label: 'State' } }, el('span', { class: 'badge', dataset: { testid: 'worker-state' } })),
    cell('Host', 'worker-host'),
    cell('Threads', 'worker-threads'),
    cell('Current task', 'worker-task'),
    cell('Samples/s', 'worker-rate'),
    cell('Samples', 'worker-samples'),
    cell('Last heartbeat', 'worker-heartbeat'),
    cell('Version', 'worker-version'));
}

function fillRow(row, w) {
  const q = (id) => row.querySelector(`[data-testid="${id}"]`);
  row.dataset.state = w.state;
  const badge = q('worker-state');
  // An untrusted worker (caught merging a wrong result) and a lost one need attention: say so in
  // words, not only colour.
  setText(badge, w.untrusted ? `${w.state}, untrusted` : w.state);
  badge.className = `badge worker-${w.untrusted ? 'untrusted' : w.state}`;
  badge.title = w.untrusted
    ? 'Merged a result other workers refuted: given no more work; its tiles are rendered again'
    : w.state === 'lost' ? 'No heartbeat for longer than a lease' : '';
  setText(q('worker-host'), w.host);
  setText(q('worker-threads'), String(w.threads));
  const task = q('worker-task');
  const key = `${w.current_task}:${w.current_job}`;
  if (task.dataset.key !== key) {
    task.dataset.key = key;
    task.replaceChildren(w.current_task === null ? '–' : el('span', {},
      `task ${w.current_task}`,
      w.current_job ? [' of ', el('a', { href: `#/jobs/${w.current_job}` }, `job ${w.current_job.slice(0, 8)}`)] : []));
  }
  setText(q('worker-rate'), fmtRate(w.samples_per_second));
  setText(q('worker-samples'), fmtInt(w.samples_done));
  const hb = q('worker-heartbeat');
  setText(hb, fmtAgo(w.last_heartbeat_ms));
  hb.title = fmtTime(w.last_heartbeat_ms);
  setText(q('worker-version'), w.version);
}
