// What every view shares: its element's data-state/data-change, and aborting its own call in flight when the
// next change comes (so the server stops work nobody will see).
import type { Material, ModelInfo } from "../../gen/loomlight/v1/loomlight_pb.js";
import { isAbort, isBusy } from "../api.js";

// A busy server says "retry later" (RESOURCE_EXHAUSTED), e.g. while the calls a quick run of edits aborted are
// still ending there: the view stays busy and tries again, after 0.2 s, doubling up to every 3 s, until it is
// served or the next change replaces it.
const busyRetryMs = (attempt: number) => Math.min(3000, 200 * 2 ** attempt);

function pause(ms: number, signal: AbortSignal): Promise<void> {
  return new Promise((resolve) => {
    const timer = setTimeout(resolve, ms);
    signal.addEventListener("abort", () => {
      clearTimeout(timer);
      resolve();
    }, { once: true });
  });
}

export interface ViewContext {
  material: Material;
  model: ModelInfo;
  change: number;
  signal: AbortSignal;
  /** Marks the element as showing this change (call right after redrawing). */
  shown(): void;
}

export type ViewState = "busy" | "done" | "error" | "hidden";

export class ViewSlot {
  private controller: AbortController | null = null;

  constructor(readonly name: string, readonly element: HTMLElement) {}

  set state(state: ViewState) {
    this.element.dataset.state = state;
    this.element.closest(".view")?.setAttribute("data-view-state", state);
  }

  /** Runs `draw` for a change; errors other than aborts go to `onError` and leave the last good content. */
  async run(
    material: Material,
    model: ModelInfo,
    change: number,
    draw: (ctx: ViewContext) => Promise<ViewState | void>,
    onError: (error: unknown) => void,
  ): Promise<void> {
    this.controller?.abort();
    const controller = new AbortController();
    this.controller = controller;
    this.state = "busy";
    const ctx: ViewContext = {
      material,
      model,
      change,
      signal: controller.signal,
      shown: () => (this.element.dataset.change = String(change)),
    };
    try {
      for (let attempt = 0; ; ++attempt) {
        try {
          const state = await draw(ctx);
          if (controller.signal.aborted) return;
          if (state === "hidden") ctx.shown();
          this.state = state ?? "done";
          return;
        } catch (error) {
          if (controller.signal.aborted || isAbort(error)) return;
          if (isBusy(error)) {
            await pause(busyRetryMs(attempt), controller.signal);
            if (controller.signal.aborted) return;
            continue;
          }
          this.state = "error";
          onError(error);
          return;
        }
      }
    } finally {
      if (this.controller === controller) this.controller = null;
    }
  }

  abort(): void {
    this.controller?.abort();
    this.controller = null;
  }
}

/** A canvas sized for the screen's pixel density, with a context in CSS pixels. */
export function hiDpi(canvas: HTMLCanvasElement, width: number, height: number): CanvasRenderingContext2D {
  const dpr = Math.max(1, Math.min(3, window.devicePixelRatio || 1));
  canvas.width = Math.round(width * dpr);
  canvas.height = Math.round(height * dpr);
  canvas.style.aspectRatio = `${width} / ${height}`;
  const g = canvas.getContext("2d")!;
  g.setTransform(dpr, 0, 0, dpr, 0, 0);
  return g;
}

export const luminance = (f: ArrayLike<number>, i: number) =>
  0.2126 * f[3 * i] + 0.7152 * f[3 * i + 1] + 0.0722 * f[3 * i + 2];

/** Evaluate's reply time in the server, for the timing log. */
export const serverTotal = (r: { totalSeconds: number }) => r.totalSeconds;
