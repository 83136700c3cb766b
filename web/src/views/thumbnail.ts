// #thumbnail: a physically based render, progressive: 1 sample per pixel first (seconds), then 8, then 32,
// each a Render call of its own. The next change aborts the stream in flight, so the server stops rendering.
import { create } from "@bufbuild/protobuf";
import type { RenderUpdate } from "../../gen/loomlight/v1/loomlight_pb.js";
import { RenderFormat, RenderRequestSchema } from "../../gen/loomlight/v1/loomlight_pb.js";
import { client } from "../api.js";
import { timed } from "../timings.js";
import { setImage } from "./slice.js";
import type { ViewContext } from "./view.js";

const SIZE = 256;
const PASSES = [1, 8, 32];

export interface ThumbnailParts {
  img: HTMLImageElement;
  progress: HTMLProgressElement;
  caption: HTMLElement;
  onFidelity: (update: RenderUpdate) => void;
}

export async function drawThumbnail(parts: ThumbnailParts, ctx: ViewContext, scene: string): Promise<void> {
  try {
    await renderPasses(parts, ctx, scene);
  } catch (error) {
    if (!ctx.signal.aborted) parts.caption.textContent = "not rendered";
    throw error;
  }
}

async function renderPasses(parts: ThumbnailParts, ctx: ViewContext, scene: string): Promise<void> {
  const { img, progress, caption } = parts;
  for (const [pass, spp] of PASSES.entries()) {
    const request = create(RenderRequestSchema, {
      material: ctx.material,
      sceneName: scene,
      width: SIZE,
      height: SIZE,
      samplesPerPixel: spp,
      seed: 1n, // the same material renders to the same image: only edits change it
      format: RenderFormat.PNG,
    });
    caption.textContent = `rendering ${spp} sample${spp > 1 ? "s" : ""} per pixel…`;
    progress.value = 0;
    const last = await timed(
      "Render",
      "thumbnail",
      async () => {
        let final: RenderUpdate | undefined;
        for await (const update of client.render(request, { signal: ctx.signal })) {
          if (update.samplesTotal > 0n) progress.value = Number(update.samplesDone) / Number(update.samplesTotal);
          if (update.image.length > 0) final = update;
        }
        if (!final) throw new Error("the render ended without an image");
        return final;
      },
      (r) => r.totalSeconds,
    );
    setImage(img, last.image, "image/png");
    img.dataset.spp = String(spp);
    if (pass === PASSES.length - 1) img.dataset.final = "true";
    else delete img.dataset.final;
    ctx.shown();
    parts.onFidelity(last);
    caption.textContent =
      `${spp} spp, ${last.totalSeconds.toFixed(2)} s in the server` +
      (pass < PASSES.length - 1 ? ", refining…" : "");
  }
  progress.value = 1;
}

/** The fidelity report of a render: per object, each modelling choice and why it was made. */
export function showFidelity(el: HTMLElement, update: RenderUpdate): void {
  el.replaceChildren();
  const head = document.createElement("p");
  head.textContent = `error target ${(update.errorTarget * 100).toFixed(1)}% per choice`;
  el.appendChild(head);
  for (const object of update.fidelity) {
    const table = document.createElement("table");
    const caption = table.createCaption();
    caption.textContent = `${object.object} — ${object.model}, estimated error ${(object.estimatedError * 100).toFixed(2)}%`;
    const headRow = table.createTHead().insertRow();
    for (const h of ["aspect", "chosen", "full", "est. error", "reason"]) {
      const th = document.createElement("th");
      th.textContent = h;
      headRow.appendChild(th);
    }
    const body = table.createTBody();
    for (const c of object.choices) {
      const row = body.insertRow();
      for (const text of [c.aspect, c.chosen, c.full, `${(c.estimatedError * 100).toFixed(2)}%`, c.reason])
        row.insertCell().textContent = text;
    }
    el.appendChild(table);
  }
}
