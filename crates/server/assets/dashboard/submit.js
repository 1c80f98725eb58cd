// The submit page: a scene file and its render settings, sent as POST /jobs (multipart `scene` +
// `settings`, and `environment` when an environment image is chosen). The server loads the scene
// and the environment before accepting them, so a broken one comes back as a 422 whose message is
// shown next to the form.

import { api } from './api.js';
import { el } from './util.js';

const STRATEGIES = [
  ['mis', 'MIS: light and BSDF sampling (best in general)'],
  ['light', 'Light sampling'],
  ['bsdf', 'BSDF sampling'],
  ['cosine', 'Cosine-weighted hemisphere'],
  ['hemisphere', 'Uniform hemisphere'],
];

function field(id, label, input, hint) {
  input.id = id;
  input.name = id;
  input.dataset.testid = `submit-${id}`;
  if (hint) input.setAttribute('aria-describedby', `${id}-hint`);
  return el('div', { class: 'field' },
    el('label', { for: id }, label), input,
    hint ? el('small', { id: `${id}-hint`, class: 'hint' }, hint) : null);
}

const num = (attrs) => el('input', { type: 'number', inputmode: 'numeric', ...attrs });

export function mount(root) {
  const error = el('p', { class: 'form-error', id: 'submit-error', role: 'alert', tabindex: -1, hidden: true, dataset: { testid: 'submit-error' } });
  const button = el('button', { type: 'submit', class: 'primary', dataset: { testid: 'submit-button' } }, 'Submit');
  const form = el('form', { class: 'submit-form', 'aria-describedby': 'submit-error', dataset: { testid: 'submit-form' } },
    field('scene', 'Scene (.glb or .gltf with embedded data)',
      el('input', { type: 'file', accept: '.glb,.gltf,model/gltf-binary,model/gltf+json', required: true })),
    field('name', 'Name', el('input', { type: 'text', maxlength: 256, placeholder: 'the file name' }), 'Optional.'),
    el('fieldset', { class: 'row' }, el('legend', {}, 'Resolution'),
      field('width', 'Width', num({ min: 1, max: 16384, value: 512, required: true })),
      field('height', 'Height', num({ min: 1, max: 16384, value: 512, required: true }))),
    el('div', { class: 'row' },
      field('spp', 'Samples per pixel', num({ min: 1, max: 1048576, value: 64, required: true })),
      field('seed', 'Seed', num({ min: 0, value: 0, required: true }))),
    field('direct', 'Direct-lighting strategy',
      el('select', {}, STRATEGIES.map(([v, l]) => el('option', { value: v }, l)))),
    el('div', { class: 'row' },
      field('noise_target', 'Noise target', num({ min: 0, step: 'any', placeholder: 'none', inputmode: 'decimal' }),
        'Stop once the estimated relative error is below this, e.g. 0.02 for 2 %.'),
      field('priority', 'Priority', num({ min: -2147483648, max: 2147483647, value: 0, required: true }), 'Higher runs first.')),
    el('details', {}, el('summary', {}, 'More settings'),
      el('div', { class: 'row' },
        field('sampler', 'Sampler', el('select', {},
          el('option', { value: 'sobol' }, 'Sobol (quasi-Monte Carlo)'), el('option', { value: 'independent' }, 'Independent'))),
        field('rr', 'Russian roulette', el('input', { type: 'text', value: 'auto', pattern: 'auto|off|max|[0-9]*\\.?[0-9]+(@[0-9]*\\.?[0-9]+)?' }),
          '“auto” (the default, 0.5@0.25), “max”, “off”, a survival probability such as 0.5, or TERMINATE@BELOW such as 0.9@0.1.')),
      el('div', { class: 'row' },
        field('max_depth', 'Max depth', num({ min: 0, placeholder: 'unlimited' }), 'Any cap is biased.'),
        field('tile_size', 'Tile size', num({ min: 1, max: 4096, value: 64 }))),
      el('div', { class: 'row' },
        field('time_limit_s', 'Time limit (s)', num({ min: 0, step: 'any', placeholder: 'none', inputmode: 'decimal' })),
        field('camera', 'Camera', el('input', { type: 'text', placeholder: 'the first one' })))),
    el('details', { dataset: { testid: 'submit-environment-section' } }, el('summary', {}, 'Environment light'),
      field('env_kind', 'Environment', el('select', {},
        el('option', { value: 'none' }, 'None (rays that leave the scene see black)'),
        el('option', { value: 'image' }, 'Image (.exr or .hdr, equirectangular)'),
        el('option', { value: 'uniform' }, 'Uniform colour'))),
      field('env_image', 'Environment image',
        el('input', { type: 'file', accept: '.exr,.hdr,image/x-exr,image/vnd.radiance' }),
        'Mapped as Blender’s Environment Texture maps it (its centre faces +X, its top row is up).'),
      el('div', { class: 'row' },
        field('env_color', 'Colour', el('input', { type: 'color', value: '#ffffff' }), 'Linear RGB, 0–1 per channel.'),
        field('env_strength', 'Strength', num({ min: 0, step: 'any', value: 1, inputmode: 'decimal' })),
        field('env_rotation', 'Rotation (°)', num({ step: 'any', value: 0, inputmode: 'decimal' }), 'About the up axis.'))),
    error,
    el('div', { class: 'buttons' }, button));

  form.addEventListener('submit', async (ev) => {
    ev.preventDefault();
    error.hidden = true;
    const v = (id) => form.elements[id].value.trim();
    const settings = {
      width: Number(v('width')),
      height: Number(v('height')),
      spp: Number(v('spp')),
      seed: Number(v('seed')),
      direct: v('direct'),
      priority: Number(v('priority')),
      sampler: v('sampler'),
      rr: v('rr') || 'auto',
      tile_size: Number(v('tile_size') || 64),
    };
    // Optional fields are sent only when set: absent means "none" to the API.
    if (v('name')) settings.name = v('name');
    if (v('noise_target')) settings.noise_target = Number(v('noise_target'));
    if (v('time_limit_s')) settings.time_limit_s = Number(v('time_limit_s'));
    if (v('max_depth')) settings.max_depth = Number(v('max_depth'));
    if (v('camera')) settings.camera = v('camera');
    const file = form.elements.scene.files[0];
    // The environment: a uniform colour in the settings, or an image uploaded as its own part
    // (the server fills in its hash); strength and rotation ride in the settings either way.
    let envFile = null;
    const kind = v('env_kind');
    if (kind !== 'none') {
      const env = { strength: Number(v('env_strength') || 1), rotation_degrees: Number(v('env_rotation') || 0) };
      if (kind === 'uniform') {
        const hex = v('env_color');
        env.radiance = [1, 3, 5].map((i) => parseInt(hex.slice(i, i + 2), 16) / 255);
      } else {
        envFile = form.elements.env_image.files[0];
        if (!envFile) {
          error.textContent = 'Choose an environment image, or set the environment to none.';
          error.hidden = false;
          error.focus();
          return;
        }
      }
      settings.environment = env;
    }
    button.disabled = true;
    button.textContent = 'Submitting…';
    try {
      const created = await api.submit(file, settings, envFile);
      location.hash = `#/jobs/${created.id}`;
    } catch (e) {
      // The server's own words: it loaded the scene and knows what is wrong with it.
      error.textContent = e.code ? `${e.message} (${e.code})` : String(e.message || e);
      error.hidden = false;
      error.focus();
    } finally {
      button.disabled = false;
      button.textContent = 'Submit';
    }
  });

  root.replaceChildren(el('section', { 'aria-labelledby': 'submit-title' },
    el('div', { class: 'page-head' }, el('h1', { id: 'submit-title' }, 'Submit a job')),
    form));
}
