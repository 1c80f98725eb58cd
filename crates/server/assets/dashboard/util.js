// Small helpers shared by the pages: building DOM, formatting numbers, polling, notices, the
// confirmation dialog.

// el('td', {class: 'num', dataset: {label: 'ETA'}}, 'text', child…): attributes by name,
// `dataset`, `on…` listeners; children are nodes or strings (text, never HTML: no injection).
export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (v === undefined || v === null || v === false) continue;
    if (k === 'dataset') Object.assign(node.dataset, v);
    else if (k.startsWith('on')) node.addEventListener(k.slice(2), v);
    else if (k === 'class') node.className = v;
    else if (v === true) node.setAttribute(k, '');
    else node.setAttribute(k, String(v));
  }
  node.append(...children.flat().filter((c) => c !== null && c !== undefined));
  return node;
}

// Sets text only when it changed, so polling does not disturb a selection or a screen reader.
export function setText(node, text) {
  if (node.textContent !== text) node.textContent = text;
}

export const JOB_STATES = ['queued', 'running', 'paused', 'completed', 'cancelled', 'failed'];
export const FINAL_STATES = new Set(['completed', 'cancelled', 'failed']);

export function fmtInt(n) {
  return Math.round(n).toLocaleString('en-US');
}

// 1234567 → "1.23 M"
export function fmtSi(n) {
  if (!Number.isFinite(n)) return '–';
  const units = [['G', 1e9], ['M', 1e6], ['k', 1e3]];
  // Number(…toPrecision(3)) drops trailing zeros: 1.5 M, 500 k, 12.
  for (const [u, f] of units) if (Math.abs(n) >= f) return `${Number((n / f).toPrecision(3))} ${u}`;
  return String(Number(n.toPrecision(3)));
}

export function fmtRate(n) {
  return n > 0 ? `${fmtSi(n)}/s` : '–';
}

export function fmtError(e) {
  if (e === null || e === undefined) return '–';
  // Three significant digits, without trailing zeros: 7.82 %, 0.1 %, 100 %.
  return `${Number((e * 100).toPrecision(3))} %`;
}

export function fmtDuration(s) {
  if (s === null || s === undefined || !Number.isFinite(s)) return '–';
  s = Math.max(0, Math.round(s));
  if (s < 60) return `${s} s`;
  if (s < 3600) return `${Math.floor(s / 60)} min ${s % 60} s`;
  return `${Math.floor(s / 3600)} h ${Math.floor((s % 3600) / 60)} min`;
}

export function fmtAgo(ms) {
  if (!ms) return '–';
  const s = (Date.now() - ms) / 1000;
  return s < 1.5 ? 'just now' : `${fmtDuration(s)} ago`;
}

export function fmtTime(ms) {
  return ms ? new Date(ms).toLocaleString() : '–';
}

export function progress(job) {
  return job.samples_planned > 0 ? job.samples_done / job.samples_planned : 0;
}

// Runs `fn` now and then again `interval()` ms after each run finishes (so slow answers never
// pile up), until `signal` aborts. Errors go to `onError` and polling goes on. Returns a function
// that polls again right away (after an action) instead of waiting for the next tick; called
// while a run is in flight, it runs once more when that one ends, never two at a time.
export function poll(fn, interval, signal, onError = showError) {
  let timer = null;
  let running = false;
  let again = false;
  const run = async () => {
    clearTimeout(timer);
    if (signal.aborted) return;
    if (running) {
      again = true;
      return;
    }
    running = true;
    try {
      await fn();
    } catch (e) {
      if (!signal.aborted && e.name !== 'AbortError') onError(e);
    }
    running = false;
    if (signal.aborted) return;
    if (again) {
      again = false;
      run();
    } else {
      timer = setTimeout(run, typeof interval === 'function' ? interval() : interval);
    }
  };
  signal.addEventListener('abort', () => clearTimeout(timer));
  run();
  return run;
}

let noticeTimer = null;
export function notice(text, kind = 'info') {
  const box = document.getElementById('notice');
  box.textContent = text;
  box.dataset.kind = kind;
  clearTimeout(noticeTimer);
  noticeTimer = setTimeout(() => (box.textContent = ''), 6000);
}

export function showError(e) {
  console.error(e);
  notice(e.code ? `${e.message} (${e.code})` : String(e.message || e), 'error');
}

// A modal question answered by the custom <dialog> in index.html (not window.confirm, which
// blocks the page's pollers and cannot be styled). Resolves to true when confirmed.
export function confirmAction(title, text, confirmLabel) {
  const dialog = document.getElementById('confirm-dialog');
  document.getElementById('confirm-title').textContent = title;
  document.getElementById('confirm-text').textContent = text;
  document.getElementById('confirm-yes').textContent = confirmLabel;
  dialog.returnValue = '';
  return new Promise((resolve) => {
    dialog.addEventListener('close', () => resolve(dialog.returnValue === 'confirm'), { once: true });
    dialog.showModal();
  });
}
