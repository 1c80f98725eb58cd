// A frame job's frame strip and player. One cell per frame, in the job's frame order, with the
// frame's progress (its fewest samples per pixel against the job's) and its estimated error
// (`data-error`, and in the tooltip); clicking a cell shows that frame in the preview and its
// history in the charts. Play steps through the frames rendered so far at the job's frames per
// second, looping, until Pause.

import { el, setText, fmtError } from './util.js';

// The fastest the player steps, whatever the job's rate: each step may fetch a preview.
const MIN_STEP_MS = 40;

// `onSelect(frame)` hears of every change of the frame shown.
export function frameStrip(onSelect) {
  let frames = [];
  let selected = null;
  let timer = null;
  let fps = 24;

  const play = el('button', { type: 'button', class: 'play', 'aria-pressed': 'false', dataset: { testid: 'frame-play' } }, 'Play');
  const summary = el('span', { class: 'muted', dataset: { testid: 'frames-summary' } });
  const cells = el('ol', { class: 'frame-strip', 'aria-label': 'Frames', dataset: { testid: 'frame-strip' } });
  const element = el('section', { class: 'frames', 'aria-labelledby': 'frames-title' },
    el('div', { class: 'frames-head' }, el('h2', { id: 'frames-title' }, 'Frames'), summary, play),
    cells);

  function mark() {
    for (const li of cells.children) {
      const on = Number(li.dataset.frame) === selected;
      li.classList.toggle('selected', on);
      li.firstChild.setAttribute('aria-pressed', String(on));
    }
  }

  function select(frame) {
    if (frame === selected) return;
    selected = frame;
    mark();
    onSelect(frame);
  }

  // The next frame with samples after the one shown (the first after the last).
  function step() {
    const ready = frames.filter((f) => f.samples_done > 0);
    if (!ready.length) return;
    const i = ready.findIndex((f) => f.frame === selected);
    select(ready[(i + 1) % ready.length].frame);
  }

  function pause() {
    clearInterval(timer);
    timer = null;
    play.textContent = 'Play';
    play.setAttribute('aria-pressed', 'false');
    element.dataset.playing = 'false';
  }

  play.addEventListener('click', () => {
    if (timer) {
      pause();
      return;
    }
    timer = setInterval(step, Math.max(1000 / fps, MIN_STEP_MS));
    play.textContent = 'Pause';
    play.setAttribute('aria-pressed', 'true');
    element.dataset.playing = 'true';
  });

  function update(job) {
    frames = job.frames || [];
    fps = job.settings.fps || 24;
    const spp = job.settings.spp;
    if (selected === null && frames.length) selected = frames[0].frame;
    frames.forEach((f, i) => {
      let li = cells.children[i];
      if (!li) {
        const button = el('button', { type: 'button', onclick: () => select(Number(li.dataset.frame)) },
          el('span', { class: 'frame-number' }), el('progress', { max: 1, value: 0, 'aria-hidden': 'true' }));
        li = el('li', { dataset: { testid: 'frame-cell' } }, button);
        cells.append(li);
      }
      const done = Math.min(1, f.samples_per_pixel / spp);
      li.dataset.frame = String(f.frame);
      li.dataset.complete = String(f.complete);
      li.classList.toggle('complete', f.complete);
      const button = li.firstChild;
      setText(button.firstChild, String(f.frame));
      if (Number(button.lastChild.value) !== done) button.lastChild.value = done;
      li.dataset.error = f.relative_error == null ? '' : String(f.relative_error);
      button.title = `Frame ${f.frame}: ${f.samples_per_pixel} / ${spp} samples per pixel, error ${fmtError(f.relative_error)}${f.complete ? ', complete' : ''}`;
    });
    while (cells.children.length > frames.length) cells.lastChild.remove();
    setText(summary, `${job.frames_done ?? 0} of ${job.frames_total ?? frames.length} complete, ${fps} fps`);
    play.disabled = !frames.some((f) => f.samples_done > 0);
    if (play.disabled && timer) pause();
    mark();
  }

  return { element, update, selected: () => selected, playing: () => timer !== null, destroy: pause };
}
