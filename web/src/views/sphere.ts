// #sphere: a sphere lit by one distant light, seen along the axis, each pixel's radiance f cos(theta_i) from
// one Evaluate call; spatially varying models get uv from the sphere's longitude and latitude.
import { create } from "@bufbuild/protobuf";
import { EvaluateRequestSchema } from "../../gen/loomlight/v1/loomlight_pb.js";
import { client } from "../api.js";
import { toByte } from "../color.js";
import { timed } from "../timings.js";
import { hiDpi, serverTotal, type ViewContext } from "./view.js";

const N = 88; // pixels across: about 4,000 queries on the lit part of the disc
const LIGHT = (() => {
  const l = [-0.5, 0.55, 0.67];
  const n = Math.hypot(...l);
  return l.map((x) => x / n);
})();
const REPEATS_U = 8; // pattern repeats around the sphere, and from pole to pole
const REPEATS_V = 4;

export async function drawSphere(canvas: HTMLCanvasElement, ctx: ViewContext): Promise<void> {
  const wi: number[] = [];
  const wo: number[] = [];
  const uv: number[] = [];
  const pixel: number[] = [];
  const cosines: number[] = [];
  for (let py = 0; py < N; py++)
    for (let px = 0; px < N; px++) {
      const x = ((px + 0.5) / N) * 2 - 1;
      const y = 1 - ((py + 0.5) / N) * 2;
      const z2 = 1 - x * x - y * y;
      if (z2 <= 0) continue;
      const n = [x, y, Math.sqrt(z2)];
      const lon = Math.atan2(x, n[2]);
      // Shading frame: t along increasing longitude (texture u), b = n x t (texture v, toward the north pole).
      const t = [Math.cos(lon), 0, -Math.sin(lon)];
      const b = [n[1] * t[2] - n[2] * t[1], n[2] * t[0] - n[0] * t[2], n[0] * t[1] - n[1] * t[0]];
      const local = (v: number[]) => [
        v[0] * t[0] + v[1] * t[1] + v[2] * t[2],
        v[0] * b[0] + v[1] * b[1] + v[2] * b[2],
        v[0] * n[0] + v[1] * n[1] + v[2] * n[2],
      ];
      const l = local(LIGHT);
      if (l[2] <= 0) continue; // in shadow: no light, nothing to ask
      wi.push(...l);
      wo.push(...local([0, 0, 1]));
      uv.push((lon / (2 * Math.PI) + 0.5) * REPEATS_U, (Math.asin(y) / Math.PI + 0.5) * REPEATS_V);
      pixel.push(py * N + px);
      cosines.push(l[2]);
    }
  const request = create(EvaluateRequestSchema, {
    material: ctx.material,
    wi,
    wo,
    uv: ctx.model.spatiallyVarying ? uv : [],
  });
  const reply = await timed("Evaluate", "sphere", () => client.evaluate(request, { signal: ctx.signal }), serverTotal);

  // Exposure: the 98th percentile of the lit pixels maps to white; small highlights may clip, as on film.
  const radiance = pixel.map((_, k) => [0, 1, 2].map((c) => reply.f[3 * k + c] * cosines[k] * Math.PI));
  const sorted = radiance.map((r) => Math.max(...r)).sort((a, b) => a - b);
  const white = sorted[Math.floor(0.98 * (sorted.length - 1))] || 1;
  const image = new ImageData(N, N);
  for (let py = 0; py < N; py++)
    for (let px = 0; px < N; px++) {
      const x = ((px + 0.5) / N) * 2 - 1;
      const y = 1 - ((py + 0.5) / N) * 2;
      // The disc in shadow is a dark grey, not the background: the sphere's outline stays visible.
      image.data.set(x * x + y * y < 1 ? [10, 10, 12, 255] : [0, 0, 0, 0], 4 * (py * N + px));
    }
  radiance.forEach((r, k) => image.data.set([...r.map((v) => toByte(v / white)), 255], 4 * pixel[k]));

  const S = 300;
  const g = hiDpi(canvas, S, S);
  const off = new OffscreenCanvas(N, N);
  off.getContext("2d")!.putImageData(image, 0, 0);
  g.clearRect(0, 0, S, S);
  g.imageSmoothingEnabled = true;
  g.imageSmoothingQuality = "high";
  // Clipped to the disc so its outline is smooth however coarse the Evaluate grid.
  g.save();
  g.beginPath();
  g.arc(S / 2, S / 2, S / 2 - 10, 0, 2 * Math.PI);
  g.clip();
  g.drawImage(off, 10, 10, S - 20, S - 20);
  g.restore();
  const ink = getComputedStyle(document.documentElement).getPropertyValue("--ink").trim() || "#ddd";
  g.fillStyle = ink;
  g.font = "11px system-ui, sans-serif";
  g.fillText("light ↖ from upper left", 8, S - 8);
  ctx.shown();
}
