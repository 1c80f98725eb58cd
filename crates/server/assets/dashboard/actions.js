// The job actions shared by the jobs list and the job page: pause, resume, cancel, delete (the last
// two irreversible, so confirmed first) and the priority field.

import { api } from './api.js';
import { el, confirmAction, notice, showError, FINAL_STATES } from './util.js';

const ACTIONS = [
  { action: 'pause', label: 'Pause', allowed: (s) => s === 'queued' || s === 'running' },
  { action: 'resume', label: 'Resume', allowed: (s) => s === 'paused' },
  { action: 'cancel', label: 'Cancel', allowed: (s) => !FINAL_STATES.has(s), danger: true },
  { action: 'delete', label: 'Delete', allowed: () => true, danger: true },
];

async function run(action, job) {
  const name = `“${job.name}”`;
  switch (action) {
    case 'pause':
      await api.pause(job.id);
      notice(`Paused ${name}.`);
      return;
    case 'resume':
      await api.resume(job.id);
      notice(`Resumed ${name}.`);
      return;
    case 'cancel':
      if (!(await confirmAction(`Cancel ${name}?`,
        'Rendering stops for good; the image so far stays available.', 'Cancel the job'))) return;
      await api.cancel(job.id);
      notice(`Cancelled ${name}.`);
      return;
    case 'delete':
      if (!(await confirmAction(`Delete ${name}?`,
        'The job, its image and its history are removed. This cannot be undone.', 'Delete the job'))) return;
      await api.remove(job.id);
      notice(`Deleted ${name}.`);
      return 'deleted';
  }
}

// Buttons for `job`; `getJob()` gives the freshest JobView when clicked, `after(result)` runs
// after a successful action (to refresh right away).
export function actionButtons(getJob, after) {
  const box = el('div', { class: 'actions', role: 'group', 'aria-label': 'Job actions' });
  for (const a of ACTIONS) {
    const b = el('button', {
      type: 'button',
      class: a.danger ? 'danger small' : 'small',
      dataset: { action: a.action, testid: `action-${a.action}` },
      onclick: async () => {
        b.disabled = true;
        try {
          after(await run(a.action, getJob()));
        } catch (e) {
          showError(e);
        } finally {
          updateActionButtons(box, getJob());
        }
      },
    }, a.label);
    box.append(b);
  }
  updateActionButtons(box, getJob());
  return box;
}

export function updateActionButtons(box, job) {
  for (const a of ACTIONS) {
    const b = box.querySelector(`[data-action="${a.action}"]`);
    const ok = a.allowed(job.state);
    if (b.disabled === ok) b.disabled = !ok;
    b.setAttribute('aria-label', `${a.label} ${job.name}`);
  }
}

// A number field that sets the priority on Enter or when it loses focus after an edit. Polling
// leaves it alone while it has focus, so typing is never overwritten.
export function priorityField(getJob, after, id) {
  const input = el('input', {
    type: 'number', step: '1', min: '-2147483648', max: '2147483647', class: 'priority',
    id, dataset: { testid: 'priority' }, inputmode: 'numeric',
  });
  input.value = String(getJob().priority);
  let sending = false;
  const commit = async () => {
    const job = getJob();
    const text = input.value.trim();
    const p = Number(text);
    // Not a whole number (or emptied to type a new one): nothing to send; once the field loses
    // focus the next poll shows the current priority again.
    if (text === '' || !Number.isInteger(p)) return;
    if (p === job.priority || sending) return;
    sending = true;
    try {
      const updated = await api.setPriority(job.id, p);
      notice(`Priority of “${job.name}” is now ${updated.priority}.`);
      after(updated);
    } catch (e) {
      showError(e);
      input.value = String(job.priority);
    } finally {
      sending = false;
    }
  };
  input.addEventListener('change', commit);
  // Enter does not always fire `change` on a number field outside a form.
  input.addEventListener('keydown', (ev) => {
    if (ev.key === 'Enter') commit();
  });
  return input;
}

export function updatePriorityField(input, job) {
  if (document.activeElement !== input && input.value !== String(job.priority)) {
    input.value = String(job.priority);
  }
}
