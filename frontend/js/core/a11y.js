// Screen-reader announcements (two live regions in index.html) and accessible names for the drive pads,
// whose buttons show only glyphs. Kept out of drive.js on purpose: the names are set on the buttons that
// DrivePad builds (it never replaces them, only their title and disabled state).

const DRIVE_NAMES = {
  "drive-forward": "Drive forward (hold)",
  "drive-backward": "Drive backward (hold)",
  "drive-left": "Turn left (hold)",
  "drive-right": "Turn right (hold)",
  "drive-stop": "Stop this robot",
};

/** Says ``text`` through the live region: ``urgent`` interrupts (e-stop), otherwise it waits its turn. */
export function announce(text, urgent = false) {
  const region = document.getElementById(urgent ? "announce-alert" : "announce-polite");
  if (!region) return;
  // the same text twice in a row is announced again only if the node's content changes
  region.textContent = "";
  requestAnimationFrame(() => (region.textContent = text));
}

/** Lists that scroll (command log, events) take the keyboard focus, so Page Up/Down scroll them; each is
 *  named after the heading above it. */
export function focusableScrollRegions(root = document) {
  for (const list of root.querySelectorAll("ul.log")) {
    list.tabIndex = 0;
    const heading = list.previousElementSibling;
    if (heading && /^H[1-6]$/.test(heading.tagName)) list.setAttribute("aria-label", heading.textContent);
  }
}

/** Gives every drive button under ``root`` a name that says what it does. */
export function labelDrivePads(root = document) {
  for (const [testid, name] of Object.entries(DRIVE_NAMES)) {
    for (const b of root.querySelectorAll(`[data-testid=${testid}]`)) b.setAttribute("aria-label", name);
  }
  for (const pad of root.querySelectorAll(".pad")) {
    pad.setAttribute("role", "group");
    pad.setAttribute("aria-label", "Drive pad");
  }
}
