// #halfdiff: f over theta_h (x) and theta_d (y) at phi_d 90 degrees (Rusinkiewicz coordinates, phi_h 0), in
// false colour on a log scale so both the highlight and the diffuse floor read; one Evaluate call.
import { create } from "@bufbuild/protobuf";
import { EvaluateRequestSchema } from "../../gen/loomlight/v1/loomlight_pb.js";
import { client } from "../api.js";
import { timed } from "../timings.js";
import { hiDpi, luminance, serverTotal, type ViewContext } from "./view.js";

const N = 64; // 64 x 64 cells: about 3,000 queries above the surface
const RAD = Math.PI / 180;
const DECADES = 3;

// A perceptual ramp (dark blue, purple, orange, light yellow), sampled linearly.
const RAMP = [
  [13, 8, 135],
  [126, 3, 168],
  [204, 71, 120],
  [248, 149, 64],
  [240, 249, 33],
];
function ramp(t: number): [number, number, number] {
  const x = Math.min(1, Math.max(0, t)) * (RAMP.length - 1);
  const i = Math.min(RAMP.length - 2, Math.floor(x));
  const f = x - i;
  return [0, 1, 2].map((c) => RAMP[i][c] * (1 - f) + RAMP[i + 1][c] * f) as [number, number, number];
}

export async function drawHalfDiff(canvas: HTMLCanvasElement, ctx: ViewContext): Promise<void> {
  const wi: number[] = [];
  const wo: number[] = [];
  const cell: number[] = []; // grid index of each query (pairs below the surface are not asked)
  for (let j = 0; j < N; j++) {
    const td = ((j + 0.5) * 90) / N;
    for (let i = 0; i < N; i++) {
      const th = ((i + 0.5) * 90) / N;
      // Difference vector at phi_d 90 (in the half vector's frame), rotated by theta_h about y.
      const d = [0, Math.sin(td * RAD), Math.cos(td * RAD)];
      const rot = (v: number[]) => [
        v[0] * Math.cos(th * RAD) + v[2] * Math.sin(th * RAD),
        v[1],
        -v[0] * Math.sin(th * RAD) + v[2] * Math.cos(th * RAD),
      ];
      const a = rot(d);
      const b = rot([-d[0], -d[1], d[2]]);
      if (a[2] <= 0 || b[2] <= 0) continue;
      wi.push(...a);
      wo.push(...b);
      cell.push(j * N + i);
    }
  }
  const request = create(EvaluateRequestSchema, { material: ctx.material, wi, wo });
  const reply = await timed("Evaluate", "halfdiff", () => client.evaluate(request, { signal: ctx.signal }), serverTotal);

  const lum = cell.map((_, k) => luminance(reply.f, k));
  // The scale's top is the 99th percentile, not the peak: a grazing spike would push everything else to black.
  const sorted = lum.filter((x) => x > 0).sort((a, b) => a - b);
  const peak = Math.max(1e-30, sorted[Math.floor(0.99 * (sorted.length - 1))] ?? 0);
  const image = new ImageData(N, N);
  for (let k = 0; k < N * N; k++) image.data.set([40, 40, 44, 255], 4 * k); // below the surface: grey
  cell.forEach((c, k) => {
    const t = lum[k] > 0 ? 1 + Math.log10(lum[k] / peak) / DECADES : 0;
    const j = Math.floor(c / N);
    const i = c % N;
    const row = N - 1 - j; // theta_d grows upwards
    image.data.set([...ramp(t), 255], 4 * (row * N + i));
  });
  draw(canvas, image, peak);
  ctx.shown();
}

function draw(canvas: HTMLCanvasElement, image: ImageData, peak: number): void {
  const W = 350;
  const H = 280;
  const g = hiDpi(canvas, W, H);
  const ink = getComputedStyle(document.documentElement).getPropertyValue("--ink").trim() || "#ddd";
  const x0 = 40;
  const y0 = 10;
  const S = 216;
  const off = new OffscreenCanvas(N, N);
  off.getContext("2d")!.putImageData(image, 0, 0);
  g.clearRect(0, 0, W, H);
  g.imageSmoothingEnabled = false;
  g.drawImage(off, x0, y0, S, S);
  g.fillStyle = ink;
  g.strokeStyle = ink;
  g.font = "11px system-ui, sans-serif";
  g.strokeRect(x0, y0, S, S);
  for (let a = 0; a <= 90; a += 30) {
    const px = x0 + (a / 90) * S;
    const py = y0 + S - (a / 90) * S;
    g.textAlign = "center";
    g.fillText(`${a}°`, px, y0 + S + 14);
    g.textAlign = "right";
    g.fillText(`${a}°`, x0 - 4, py + 4);
  }
  g.textAlign = "center";
  g.fillText("θh (half vector from the normal)", x0 + S / 2, y0 + S + 30);
  g.save();
  g.translate(11, y0 + S / 2);
  g.rotate(-Math.PI / 2);
  g.fillText("θd (light from the half vector)", 0, 0);
  g.restore();
  // Colour bar: the top is the peak, each label a decade down.
  const bx = x0 + S + 22;
  for (let k = 0; k < S; k++) {
    const [r, gg, b] = ramp(1 - k / S);
    g.fillStyle = `rgb(${r},${gg},${b})`;
    g.fillRect(bx, y0 + k, 14, 1);
  }
  g.fillStyle = ink;
  g.textAlign = "left";
  for (let d = 0; d <= DECADES; d++) {
    const v = peak * Math.pow(10, -d);
    const label = v.toPrecision(2).replace("e+", "e");
    g.fillText((d === 0 ? "≥" : "") + label, bx + 18, y0 + (d / DECADES) * S + 4);
  }
  g.fillText("f (1/sr)", bx, y0 + S + 16);
  g.fillText("at φd 90°", bx, y0 + S + 30);
}
