// The dashboard's entry point: a hash router (#/jobs, #/jobs/{id}, #/workers, #/submit), so the
// server serves one page and its assets and every view has a URL that survives a reload.
// A page is a module with `mount(root, signal, query, ...params)`; leaving it aborts `signal`,
// which stops its pollers and releases its object URLs.

import { askToken, token } from './api.js';
import * as jobs from './jobs.js';
import * as job from './job.js';
import * as workers from './workers.js';
import * as submit from './submit.js';

const ROUTES = [
  { pattern: /^\/jobs\/?$/, page: jobs, nav: 'jobs', title: 'Jobs' },
  { pattern: /^\/jobs\/([0-9a-zA-Z_-]+)$/, page: job, nav: 'jobs', title: 'Job' },
  { pattern: /^\/workers\/?$/, page: workers, nav: 'workers', title: 'Workers' },
  { pattern: /^\/submit\/?$/, page: submit, nav: 'submit', title: 'Submit' },
];

const main = document.getElementById('main');
let current = null; // AbortController of the page on screen

function route() {
  const raw = location.hash.replace(/^#/, '') || '/jobs';
  const [path, search = ''] = raw.split('?');
  const match = ROUTES.map((r) => ({ r, m: path.match(r.pattern) })).find((x) => x.m);
  if (!match) {
    location.replace('#/jobs');
    return;
  }
  current?.abort();
  current = new AbortController();
  const { r, m } = match;
  document.title = `${r.title} · pathfarm`;
  for (const a of document.querySelectorAll('[data-nav]')) {
    if (a.dataset.nav === r.nav) a.setAttribute('aria-current', 'page');
    else a.removeAttribute('aria-current');
  }
  main.dataset.page = r.nav === 'jobs' && m[1] ? 'job' : r.nav;
  r.page.mount(main, current.signal, new URLSearchParams(search), ...m.slice(1).map(decodeURIComponent));
  // Move keyboard and screen-reader focus to the new page, as a full page load would.
  if (document.activeElement && document.activeElement !== document.body && !main.contains(document.activeElement)) {
    main.focus({ preventScroll: true });
  }
}

window.addEventListener('hashchange', route);

const change = document.getElementById('token-change');
change.hidden = !token();
change.addEventListener('click', async () => {
  if (await askToken('Enter the API token to use from now on.', { dismissable: true })) route();
});

route();
