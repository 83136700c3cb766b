// #slice: the BTF of a spatially varying material over two pattern repeats (TextureSlice PNG), lit near the
// mirror configuration so the threads' highlights show; hidden for materials that do not vary over the surface.
import { create } from "@bufbuild/protobuf";
import { ImageFormat, TextureSliceRequestSchema } from "../../gen/loomlight/v1/loomlight_pb.js";
import { client } from "../api.js";
import { timed } from "../timings.js";
import type { ViewContext, ViewState } from "./view.js";

const S30 = Math.sin(Math.PI / 6);
const C30 = Math.cos(Math.PI / 6);

export async function drawSlice(img: HTMLImageElement, ctx: ViewContext): Promise<ViewState> {
  if (!ctx.model.spatiallyVarying) {
    img.removeAttribute("src");
    return "hidden";
  }
  const request = create(TextureSliceRequestSchema, {
    material: ctx.material,
    wi: [-S30, 0, C30],
    wo: [S30 * 0.5, S30 * 0.5, Math.sqrt(1 - 0.5 * S30 * S30)],
    region: { uMin: 0, vMin: 0, uMax: 2, vMax: 2 },
    width: 256,
    height: 256,
    samplesPerPixel: 2,
    format: ImageFormat.PNG,
  });
  const reply = await timed(
    "TextureSlice",
    "slice",
    () => client.textureSlice(request, { signal: ctx.signal }),
    (r) => r.totalSeconds,
  );
  setImage(img, reply.image, "image/png");
  img.title = `mean f ${reply.mean.map((x) => x.toPrecision(3)).join(", ")} 1/sr, exposure ${reply.exposure.toPrecision(3)}`;
  ctx.shown();
  return "done";
}

/** Shows bytes in an <img> through a Blob URL, freeing the previous one. */
export function setImage(img: HTMLImageElement, bytes: Uint8Array, type: string): void {
  const old = img.src;
  img.src = URL.createObjectURL(new Blob([bytes], { type }));
  if (old.startsWith("blob:")) URL.revokeObjectURL(old);
}
