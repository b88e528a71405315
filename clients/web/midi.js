// MIDI learn, for directors: pick what a control should do (a puppet's
// keyframing cursor x or y, a skeleton's blend or key pose, a reset, the
// take's record or stop), press "learn MIDI", move the control. The daemon
// maps the next control moved on any of the stage's MIDI inputs to it,
// at once and in the stage file (docs/midi.md); the `inputs` message
// says what is awaited and what was learnt.

import { RIG_KIND, midiLearnMessage } from './protocol.js';

/** The targets a stage's puppets offer: {label, target} each. */
export function midiTargets(puppets) {
  const targets = [];
  for (const p of puppets) {
    const puppet = p.name;
    targets.push(
      { label: `${puppet}: cursor x`, target: { action: 'cursor_x', puppet } },
      { label: `${puppet}: cursor y`, target: { action: 'cursor_y', puppet } },
    );
    const poses = p.rig?.kind === RIG_KIND.SKELETON ? (p.rig.poses ?? []) : [];
    if (poses.length > 1) {
      targets.push({ label: `${puppet}: blend ${poses[0]} → ${poses[1]}`, target: { action: 'blend', puppet, poses: [poses[0], poses[1]] } });
    }
    for (const key of poses) {
      targets.push({ label: `${puppet}: key pose ${key}`, target: { action: 'key', puppet, key } });
    }
    targets.push({ label: `${puppet}: reset`, target: { action: 'reset', puppet } });
  }
  targets.push(
    { label: 'take: record', target: { action: 'record' } },
    { label: 'take: stop', target: { action: 'stop' } },
    { label: 'take: play the newest', target: { action: 'play' } },
    { label: 'take: overdub the newest', target: { action: 'overdub' } },
  );
  return targets;
}

export class MidiLearn {
  /** elements: {controls, target, learn, status}; send(message). */
  constructor(elements, { send }) {
    this.elements = elements;
    this.send = send;
    this.enabled = false;
    this.midi = null;      // the `inputs` message's `midi`, or null
    this.targets = [];
    elements.learn.addEventListener('click', () => {
      if (this.midi?.waiting) {
        this.send(midiLearnMessage());
        return;
      }
      const chosen = this.targets[elements.target.selectedIndex];
      if (chosen) this.send(midiLearnMessage(chosen.target));
    });
  }

  setEnabled(on) {
    this.enabled = on;
    this.render();
  }

  /** The stage's puppets (a `stage` message's), whose targets are offered. */
  setup(puppets) {
    this.targets = midiTargets(puppets.map((p) => ({ name: p.src?.name ?? p.name, rig: p.src?.rig ?? p.rig })));
    this.elements.target.replaceChildren(...this.targets.map((t, i) => new Option(t.label, String(i))));
    this.render();
  }

  /** An `inputs` message. */
  onInputs(msg) {
    this.midi = msg.midi ?? null;
    this.render();
  }

  render() {
    const { controls, learn, status, target } = this.elements;
    controls.hidden = !this.enabled || !this.midi || this.midi.inputs.length === 0;
    const waiting = !!this.midi?.waiting;
    learn.textContent = waiting ? 'move a control… (cancel)' : 'learn MIDI';
    learn.setAttribute('aria-pressed', String(waiting));
    target.disabled = waiting;
    if (waiting) {
      // A control the input already maps was moved: it was passed over.
      status.textContent = this.midi.passed_over ?? '';
    } else {
      status.textContent = this.midi?.error
        ? `${this.midi.learned ?? ''} (not saved: ${this.midi.error})`
        : (this.midi?.learned ?? '');
    }
  }
}
