// Drawing a Detection over its image on a canvas, and finding the chain under the pointer.
// The colours are the overlay's (service/perception/render.py, Okabe-Ito first), so the page
// and `dlo detect`'s overlay images agree on which chain is which colour.

export const PALETTE = [
  [230, 159, 0], [86, 180, 233], [0, 158, 115], [240, 228, 66], [0, 114, 178],
  [213, 94, 0], [204, 121, 167], [255, 255, 255], [255, 120, 120], [120, 120, 255],
];

export function chainColour(id) {
  const [r, g, b] = PALETTE[id % PALETTE.length];
  return `rgb(${r}, ${g}, ${b})`;
}

function segmentLength(a, b) {
  return Math.hypot(b[0] - a[0], b[1] - a[1]);
}

// Length, joints and the share of the length that was inferred (filled, not seen).
export function chainStats(chain) {
  let length = 0;
  let inferred = 0;
  for (let k = 0; k + 1 < chain.points.length; k++) {
    const piece = segmentLength(chain.points[k], chain.points[k + 1]);
    length += piece;
    if (chain.inferred[k]) inferred += piece;
  }
  return {
    id: chain.id,
    length,
    joints: chain.points.length,
    inferredShare: length > 0 ? inferred / length : 0,
    radius: chain.radius,
  };
}

// Line width in image pixels: visible on a small image, not heavy on a large one.
export function lineWidthFor(detection) {
  return Math.max(2, Math.min(detection.width, detection.height) / 240);
}

function strokePieces(ctx, chain, width) {
  // Consecutive segments with the same flag make one path: clean joins, dashes that flow.
  let start = 0;
  while (start + 1 < chain.points.length) {
    const inferred = Boolean(chain.inferred[start]);
    let end = start + 1;
    while (end + 1 < chain.points.length && Boolean(chain.inferred[end]) === inferred) end++;
    ctx.setLineDash(inferred ? [width * 3, width * 2.5] : []);
    ctx.beginPath();
    ctx.moveTo(chain.points[start][0], chain.points[start][1]);
    for (let k = start + 1; k <= end; k++) ctx.lineTo(chain.points[k][0], chain.points[k][1]);
    ctx.stroke();
    start = end;
  }
  ctx.setLineDash([]);
}

// Chains (one colour each, a dot per joint, inferred segments dashed) and a ring at each
// crossing in the colour of the strand on top. `highlight`: a chain id drawn thicker.
export function drawDetection(ctx, detection, highlight = null) {
  const width = lineWidthFor(detection);
  const byId = new Map(detection.chains.map((chain) => [chain.id, chain]));
  ctx.save();
  ctx.lineCap = "round";
  ctx.lineJoin = "round";
  for (const chain of detection.chains) {
    const lit = chain.id === highlight;
    const colour = chainColour(chain.id);
    ctx.strokeStyle = "rgba(0, 0, 0, 0.55)"; // a dark rim keeps light colours readable
    ctx.lineWidth = width * (lit ? 3.4 : 2.1);
    strokePieces(ctx, chain, width);
    ctx.strokeStyle = colour;
    ctx.lineWidth = width * (lit ? 2.4 : 1.3);
    strokePieces(ctx, chain, width);
    ctx.fillStyle = colour;
    ctx.strokeStyle = "rgba(0, 0, 0, 0.7)";
    ctx.lineWidth = Math.max(1, width * 0.4);
    const dot = width * (lit ? 1.5 : 1.1);
    for (const [x, y] of chain.points) {
      ctx.beginPath();
      ctx.arc(x, y, dot, 0, 2 * Math.PI);
      ctx.fill();
      ctx.stroke();
    }
  }
  for (const crossing of detection.crossings || []) {
    const over = byId.get(crossing.over);
    const ring = Math.max(width * 5, over ? over.radius * 1.8 : 0);
    ctx.beginPath();
    ctx.arc(crossing.x, crossing.y, ring, 0, 2 * Math.PI);
    ctx.strokeStyle = "rgba(0, 0, 0, 0.6)";
    ctx.lineWidth = width * 2.2;
    ctx.stroke();
    ctx.strokeStyle = chainColour(crossing.over);
    ctx.lineWidth = width * 1.2;
    ctx.stroke();
  }
  ctx.restore();
}

function distanceToSegment(x, y, a, b) {
  const dx = b[0] - a[0];
  const dy = b[1] - a[1];
  const squared = dx * dx + dy * dy;
  const t = squared > 0 ? Math.max(0, Math.min(1, ((x - a[0]) * dx + (y - a[1]) * dy) / squared)) : 0;
  return Math.hypot(x - (a[0] + t * dx), y - (a[1] + t * dy));
}

// The chain nearest to (x, y) in image pixels, within its radius plus `tolerance`; or null.
export function chainAt(detection, x, y, tolerance) {
  let best = null;
  let bestDistance = Infinity;
  for (const chain of detection.chains) {
    for (let k = 0; k + 1 < chain.points.length; k++) {
      const distance = distanceToSegment(x, y, chain.points[k], chain.points[k + 1]);
      if (distance < bestDistance && distance <= chain.radius + tolerance) {
        best = chain;
        bestDistance = distance;
      }
    }
  }
  return best;
}

// A panel with a message, so that a canvas is never left blank.
export function drawPlaceholder(ctx, lines, image = null) {
  const { width, height } = ctx.canvas;
  ctx.save();
  if (image) {
    ctx.drawImage(image, 0, 0, width, height);
    ctx.fillStyle = "rgba(17, 21, 28, 0.6)";
  } else {
    ctx.fillStyle = "#1d2430";
  }
  ctx.fillRect(0, 0, width, height);
  const size = Math.max(14, Math.round(Math.min(width, height) / 22));
  ctx.font = `${size}px system-ui, sans-serif`;
  ctx.fillStyle = "#ffffff";
  ctx.textAlign = "center";
  ctx.textBaseline = "middle";
  const top = height / 2 - ((lines.length - 1) * size * 1.4) / 2;
  lines.forEach((line, index) => ctx.fillText(line, width / 2, top + index * size * 1.4, width * 0.92));
  ctx.restore();
}

// Mouse position on a canvas drawn at a scale, in the canvas's (image's) pixels.
export function imagePoint(canvas, event) {
  const box = canvas.getBoundingClientRect();
  return {
    x: ((event.clientX - box.left) * canvas.width) / box.width,
    y: ((event.clientY - box.top) * canvas.height) / box.height,
    perPixel: canvas.width / box.width,
  };
}

// Where the tooltip goes: beside the pointer, inside the stage.
export function placeTooltip(tooltip, stage, event) {
  const box = stage.getBoundingClientRect();
  let left = event.clientX - box.left + 14;
  let top = event.clientY - box.top + 14;
  const width = tooltip.offsetWidth;
  const height = tooltip.offsetHeight;
  if (left + width > box.width) left = Math.max(0, event.clientX - box.left - width - 14);
  if (top + height > box.height) top = Math.max(0, event.clientY - box.top - height - 14);
  tooltip.style.left = `${left}px`;
  tooltip.style.top = `${top}px`;
}

export function describeChain(chain) {
  const stats = chainStats(chain);
  return [
    `chain ${stats.id}`,
    `length ${stats.length.toFixed(1)} px`,
    `${stats.joints} joints`,
    `${(stats.inferredShare * 100).toFixed(0)} % inferred`,
  ];
}

// Show the chain under the pointer in a tooltip; returns its id (or null).
export function hover(canvas, tooltip, detection, event) {
  if (!detection) {
    tooltip.hidden = true;
    return null;
  }
  const point = imagePoint(canvas, event);
  const chain = chainAt(detection, point.x, point.y, 6 * point.perPixel);
  if (!chain) {
    tooltip.hidden = true;
    return null;
  }
  const [title, ...rest] = describeChain(chain);
  tooltip.replaceChildren();
  const strong = document.createElement("strong");
  strong.textContent = title;
  tooltip.append(strong, document.createElement("br"), rest.join(" · "));
  tooltip.style.borderLeftColor = chainColour(chain.id);
  tooltip.hidden = false;
  placeTooltip(tooltip, canvas.parentElement, event);
  return chain.id;
}
