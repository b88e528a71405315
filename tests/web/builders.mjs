// Prints, one JSON text a line, a message from every builder of
// clients/web/protocol.js, optional arguments both left out and given. The
// daemon's test (crates/daemon/tests/it/web_protocol.rs) reads each into
// its own `ClientMessage` type, which refuses unknown or missing fields: so
// the page's builders and the Rust types agree on every message's shape,
// not only its name, and a message type no builder makes fails there.
import * as p from '../../clients/web/protocol.js';

const messages = [
  p.helloMessage(p.ROLE.VIEWER),
  p.helloMessage(p.ROLE.PERFORMER, 'secret'),
  p.contactsMessage([p.contactDown(1, 10, 20), p.contactMove(2, -1.5, 3), p.contactUp(3)]),
  p.pinMessage(1, 2),
  p.depthFlipMessage(3, 4),
  p.unpinMessage(0, 7),
  p.paintMessage(0, 1, 2, 30, 2),
  p.paintMessage(0, 1, 2, 30, 0.5, 9),
  p.paintDepthMessage(0, 1, 2, 30, 3),
  p.paintDepthMessage(0, 1, 2, 30, 3, 9),
  p.addCurveMessage('rope', [[0, 0], [100, 50]], 12, '#aa3311'),
  p.saveWeightsMessage(0),
  p.exportGridMessage(0),
  p.poseMessage(0, 'rest', 'cheer', 0.5),
  p.recordMessage(),
  p.recordMessage('take-007'),
  p.stopRecordingMessage(),
  p.listTakesMessage(),
  p.playMessage('take-001'),
  p.playMessage('take-001', true, { replace: [p.replaceRegion(0, [10, 20], 50)], replaceSources: ['mouse'] }),
  p.stopPlayingMessage(),
  p.keyAddMessage(0, [0.5, 0.5]),
  p.keyAddMessage(0, [0.25, 0.75], 'wave'),
  p.keyMoveMessage(0, 1, [0.1, 0.9]),
  p.keyDeleteMessage(0, 1),
  p.cursorMessage(0),
  p.cursorMessage(0, [0.3, 0.3]),
  p.saveKeysMessage(0),
  p.pingMessage(123.5),
  p.undoMessage(0),
  p.redoMessage(0),
  p.resetMessage(0),
  p.replayMessage('gesture', false),
  p.releaseMessage('tuio:table'),
  p.midiLearnMessage(),
  p.midiLearnMessage({ action: 'blend', puppet: 'skeleton', poses: ['rest', 'cheer'] }),
  p.midiLearnMessage({ action: 'key', puppet: 'skeleton', key: 'cheer', seconds: 2 }),
  p.removePuppetMessage(2),
  p.orderPuppetsMessage([1, 0]),
];
for (const message of messages) console.log(p.encodeClientMessage(message));
