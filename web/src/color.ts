// Colour pickers speak sRGB hex; the API speaks linear RGB: convert through the sRGB transfer curve.
export function linearToSrgb(x: number): number {
  const c = Math.min(1, Math.max(0, x));
  return c <= 0.0031308 ? 12.92 * c : 1.055 * Math.pow(c, 1 / 2.4) - 0.055;
}

export function srgbToLinear(x: number): number {
  return x <= 0.04045 ? x / 12.92 : Math.pow((x + 0.055) / 1.055, 2.4);
}

export function linearToHex(rgb: number[]): string {
  return (
    "#" +
    rgb
      .slice(0, 3)
      .map((v) => Math.round(linearToSrgb(v) * 255).toString(16).padStart(2, "0"))
      .join("")
  );
}

/** Linear values of a picker's hex, rounded to 3 decimals so the numbers shown are the ones sent. */
export function hexToLinear(hex: string): number[] {
  const out: number[] = [];
  for (let i = 0; i < 3; i++) {
    const byte = parseInt(hex.slice(1 + 2 * i, 3 + 2 * i), 16);
    out.push(Math.round(srgbToLinear(byte / 255) * 1000) / 1000);
  }
  return out;
}

/** Tone maps a linear value (already exposed) to an 8-bit sRGB code. */
export function toByte(x: number): number {
  return Math.round(linearToSrgb(x) * 255);
}
