// A headless browser's profile folder (its --user-data-dir), removed when a
// script is done with the browser.

import fs from 'node:fs';

/**
 * Removes a browser's profile folder. A browser not yet closed may still be
 * writing into it: removal retries a little, and a folder it cannot remove
 * is told in `summary.profileLeft`, never turned into a failed check.
 */
export function removeProfile(dir, summary) {
  try {
    fs.rmSync(dir, { recursive: true, force: true, maxRetries: 10, retryDelay: 50 });
  } catch (err) {
    summary.profileLeft = `${dir} (${err.code ?? err.message})`;
  }
}
