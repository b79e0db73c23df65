// Draws AprilTag detections over a camera frame: outline, id, centre and the tag's pose axes projected
// with the robot's camera intrinsics. Coordinates are image pixels; the canvas is sized to the image.

function project(cam, p) {
  if (p[2] <= 1e-6) return null;
  return [cam.fx * (p[0] / p[2]) + cam.cx, cam.fy * (p[1] / p[2]) + cam.cy];
}

function transform(R, t, p) {
  return [0, 1, 2].map((i) => R[i][0] * p[0] + R[i][1] * p[1] + R[i][2] * p[2] + t[i]);
}

/** Tag edge length in mm, estimated from the pose and the outline (the message does not carry it). */
function edgeMm(det, cam) {
  const [a, b] = [det.corners[0], det.corners[1]];
  const px = Math.hypot(a[0] - b[0], a[1] - b[1]);
  return (px * det.translation_mm[2]) / cam.fx;
}

export function drawDetections(canvas, message) {
  const ctx = canvas.getContext("2d");
  const [w, h] = message.image_size;
  if (canvas.width !== w || canvas.height !== h) {
    canvas.width = w;
    canvas.height = h;
  }
  ctx.clearRect(0, 0, w, h);
  const cam = message.camera;
  const lw = Math.max(2, w / 320);
  ctx.lineJoin = "round";
  for (const det of message.detections ?? []) {
    ctx.strokeStyle = "#00e5ff";
    ctx.lineWidth = lw;
    ctx.beginPath();
    det.corners.forEach(([u, v], i) => (i ? ctx.lineTo(u, v) : ctx.moveTo(u, v)));
    ctx.closePath();
    ctx.stroke();
    const [cu, cv] = det.center;
    ctx.fillStyle = "#ff2d95";
    ctx.beginPath();
    ctx.arc(cu, cv, lw * 1.6, 0, 2 * Math.PI);
    ctx.fill();
    if (cam && det.rotation && det.translation_mm) {
      const L = edgeMm(det, cam) / 2;
      const origin = project(cam, det.translation_mm);
      const axes = [
        [[L, 0, 0], "#ff3b30"],
        [[0, L, 0], "#34c759"],
        [[0, 0, -L], "#0a84ff"], // out of the tag, towards the camera
      ];
      if (origin) {
        for (const [p, color] of axes) {
          const end = project(cam, transform(det.rotation, det.translation_mm, p));
          if (!end) continue;
          ctx.strokeStyle = color;
          ctx.lineWidth = lw * 1.3;
          ctx.beginPath();
          ctx.moveTo(origin[0], origin[1]);
          ctx.lineTo(end[0], end[1]);
          ctx.stroke();
        }
      }
    }
    const label = `id ${det.tag_id}${det.translation_mm ? ` · ${(det.translation_mm[2] / 1000).toFixed(2)} m` : ""}`;
    ctx.font = `${Math.round(12 * (w / 640)) + 2}px system-ui, sans-serif`;
    const tw = ctx.measureText(label).width;
    const [lu, lv] = det.corners[3] ?? det.center;
    ctx.fillStyle = "rgba(0,0,0,.65)";
    ctx.fillRect(lu, lv - 18 * (w / 640) - 4, tw + 8, 18 * (w / 640) + 4);
    ctx.fillStyle = "#fff";
    ctx.fillText(label, lu + 4, lv - 6);
  }
}
