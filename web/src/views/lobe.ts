// #lobe: f cos(theta_o) as a polar plot in the plane of incidence (phi 0) and the perpendicular plane (phi 90),
// for light at 30 and 60 degrees: one Evaluate call for all four curves.
import { create } from "@bufbuild/protobuf";
import { EvaluateRequestSchema } from "../../gen/loomlight/v1/loomlight_pb.js";
import { client } from "../api.js";
import { timed } from "../timings.js";
import { hiDpi, luminance, serverTotal, type ViewContext } from "./view.js";

const INCIDENCES = [30, 60];
const PLANES = [0, 90];
const COLOURS: Record<number, string> = { 30: "#e8a13c", 60: "#4fa3e0" };
const RAD = Math.PI / 180;
const DECADES = 3; // log radius: the peak at the rim, a thousandth of it at the centre
type Vec = [number, number, number];

const add = (a: Vec, b: Vec, s: number): Vec => [a[0] + s * b[0], a[1] + s * b[1], a[2] + s * b[2]];
const scale = (a: Vec, s: number): Vec => [a[0] * s, a[1] * s, a[2] * s];
const dot = (a: Vec, b: Vec) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a: Vec, b: Vec): Vec => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const norm = (a: Vec): Vec => scale(a, 1 / Math.hypot(...a));

/**
 * The frame the angles are measured in. Surfaces: normal +z, plane phi 0 = x-z. Fiber models (f about the
 * fiber's axis t, as `loomlight plot` draws them): "normal" u = +z made perpendicular to t; phi 0 is the
 * t-u plane (longitudinal), phi 90 the u-v plane around the axis (azimuthal).
 */
function frame(axis: number[] | null): { n: Vec; x: Vec; y: Vec } {
  if (!axis) return { n: [0, 0, 1], x: [1, 0, 0], y: [0, 1, 0] };
  let t = norm([axis[0] ?? 1, axis[1] ?? 0, axis[2] ?? 0]);
  if (!Number.isFinite(t[0])) t = [1, 0, 0];
  let u = add([0, 0, 1], t, -t[2]);
  u = Math.hypot(...u) < 1e-6 ? [1, 0, 0] : norm(u);
  return { n: u, x: t, y: cross(t, u) };
}

export async function drawLobe(
  canvas: HTMLCanvasElement,
  ctx: ViewContext,
  axis: number[] | null,
): Promise<void> {
  const fiber = axis !== null;
  const full = fiber || ctx.model.transmission || !!ctx.material.transmission; // light goes below the surface too
  const count = full ? 720 : 360;
  const span = full ? 360 : 180;
  const thetas = Array.from({ length: count }, (_, k) => -span / 2 + ((k + 0.5) * span) / count);
  const { n, x, y } = frame(axis);
  const wi: number[] = [];
  const wo: number[] = [];
  for (const ti of INCIDENCES)
    for (const phi of PLANES) {
      // The light at -theta_i in the plane of incidence, so the mirror direction is at +theta_i.
      const light = add(scale(n, Math.cos(ti * RAD)), x, -Math.sin(ti * RAD));
      const inPlane = phi === 0 ? x : y;
      for (const to of thetas) {
        wi.push(...light);
        wo.push(...add(scale(n, Math.cos(to * RAD)), inPlane, Math.sin(to * RAD)));
      }
    }
  const request = create(EvaluateRequestSchema, { material: ctx.material, wi, wo });
  const reply = await timed("Evaluate", "lobe", () => client.evaluate(request, { signal: ctx.signal }), serverTotal);

  // f cos(theta_o): surfaces' cosine to the normal; fibers' to the plane normal to the axis.
  const curves = INCIDENCES.flatMap((ti, a) =>
    PLANES.map((phi, b) => {
      const base = (a * PLANES.length + b) * count;
      const r = thetas.map((to, k) => {
        const w = wo.slice(3 * (base + k), 3 * (base + k) + 3) as Vec;
        const cos = fiber ? Math.sqrt(Math.max(0, 1 - dot(w, x) ** 2)) : Math.abs(dot(w, n));
        return Math.max(0, luminance(reply.f, base + k) * cos);
      });
      return { ti, phi, r };
    }),
  );
  last = { canvas, curves, thetas, full, fiber };
  replot();
  ctx.shown();
}

type Curve = { ti: number; phi: number; r: number[] };
let last: { canvas: HTMLCanvasElement; curves: Curve[]; thetas: number[]; full: boolean; fiber: boolean } | null = null;
let logRadius = true;

/** Switches the radius between log (small lobes beside a strong one stay visible) and linear; no new call. */
export function setLogRadius(on: boolean): void {
  logRadius = on;
  replot();
}

function replot(): void {
  if (last) plot(last.canvas, last.curves, last.thetas, last.full, last.fiber);
}

function niceMax(x: number): number {
  if (!(x > 0) || !Number.isFinite(x)) return 1;
  const p = Math.pow(10, Math.floor(Math.log10(x)));
  for (const m of [1, 1.5, 2, 3, 4, 5, 6, 8, 10]) if (m * p >= x) return m * p;
  return 10 * p;
}

function plot(
  canvas: HTMLCanvasElement,
  curves: Curve[],
  thetas: number[],
  full: boolean,
  fiber: boolean,
): void {
  const W = 520;
  const H = full ? 420 : 290;
  const g = hiDpi(canvas, W, H);
  const cx = W / 2;
  const cy = full ? H / 2 + 10 : H - 40;
  const R = full ? 150 : 200;
  const peak = Math.max(1e-30, ...curves.flatMap((c) => c.r));
  const top = niceMax(peak);
  // Radius of a value: linear up to `top`, or DECADES decades below it on the log scale.
  const radius = (v: number) =>
    logRadius ? R * Math.max(0, 1 + Math.log10(Math.max(v, 1e-30) / top) / DECADES) : (R * v) / top;
  const rings = logRadius
    ? Array.from({ length: DECADES }, (_, d) => top * Math.pow(10, -d))
    : [1, 2, 3, 4].map((q) => (top * q) / 4);
  const style = getComputedStyle(document.documentElement);
  const ink = style.getPropertyValue("--ink").trim() || "#ddd";
  const faint = style.getPropertyValue("--grid").trim() || "#444";
  g.clearRect(0, 0, W, H);
  g.font = "11px system-ui, sans-serif";
  g.lineWidth = 1;

  // Rings labelled in 1/sr: quarters of the scale (linear) or decades (log).
  g.strokeStyle = faint;
  g.fillStyle = ink;
  for (const v of rings) {
    const rr = radius(v);
    g.beginPath();
    g.arc(cx, cy, rr, full ? 0 : Math.PI, 2 * Math.PI);
    g.stroke();
    g.textAlign = "right"; // inside its ring, clear of the 90 degree label
    g.fillText(String(Number(v.toPrecision(3))), cx + rr - 2, cy - 3);
  }
  // Spokes every 30 degrees from the normal, labelled with theta_o.
  for (let a = full ? -150 : -90; a <= (full ? 180 : 90); a += 30) {
    const s = Math.sin(a * RAD);
    const c = Math.cos(a * RAD);
    g.beginPath();
    g.moveTo(cx, cy);
    g.lineTo(cx + R * s, cy - R * c);
    g.stroke();
    g.textAlign = "center";
    g.fillText(`${a}°`, cx + (R + 13) * s, cy - (R + 13) * c + 4);
  }
  g.textAlign = "left";
  // The surface (or, for fibers, the plane normal to the axis).
  g.strokeStyle = ink;
  g.beginPath();
  g.moveTo(cx - R - 4, cy);
  g.lineTo(cx + R + 4, cy);
  g.stroke();

  for (const c of curves) {
    g.strokeStyle = COLOURS[c.ti];
    g.lineWidth = 2;
    g.setLineDash(c.phi === 0 ? [] : [5, 4]);
    g.beginPath();
    c.r.forEach((v, k) => {
      const rr = radius(v);
      const px = cx + rr * Math.sin(thetas[k] * RAD);
      const py = cy - rr * Math.cos(thetas[k] * RAD);
      if (k === 0) g.moveTo(px, py);
      else g.lineTo(px, py);
    });
    g.stroke();
    // The light's direction, a short tick outside the rings.
    g.setLineDash([]);
    g.lineWidth = 3;
    const s = Math.sin(-c.ti * RAD);
    const co = Math.cos(-c.ti * RAD);
    g.beginPath();
    g.moveTo(cx + (R + 24) * s, cy - (R + 24) * co);
    g.lineTo(cx + (R + 34) * s, cy - (R + 34) * co);
    g.stroke();
  }
  g.setLineDash([]);
  g.lineWidth = 1;

  // Legend: colour = incidence, dash = plane.
  g.fillStyle = ink;
  g.fillText(fiber ? "f·cos θo about the fiber axis, luminance (1/sr)" : "f·cos θo, luminance (1/sr)", 8, 14);
  g.fillText(`peak ${peak.toPrecision(3)}`, 8, 28);
  g.fillText(logRadius ? `radius: log, ${DECADES} decades` : "radius: linear", 8, 42);
  const legend: [string, string, number[]][] = [
    ["θi 30°", COLOURS[30], []],
    ["θi 60°", COLOURS[60], []],
    [fiber ? "longitudinal (φ 0)" : "plane of incidence (φ 0)", ink, []],
    [fiber ? "around the axis (φ 90)" : "perpendicular (φ 90)", ink, [5, 4]],
  ];
  legend.forEach(([label, colour, dash], i) => {
    // Two columns in the top corners: incidences left, planes right.
    const lx = i < 2 ? 8 : W - 168;
    const ly = i < 2 ? H - 22 + i * 14 : 14 + (i - 2) * 14;
    g.strokeStyle = colour;
    g.lineWidth = 2;
    g.setLineDash(dash);
    g.beginPath();
    g.moveTo(lx, ly - 4);
    g.lineTo(lx + 22, ly - 4);
    g.stroke();
    g.setLineDash([]);
    g.fillText(label, lx + 28, ly);
  });
}
