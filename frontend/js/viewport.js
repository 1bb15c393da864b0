// Zoom and pan of one image on a canvas. Image coordinates follow the conventions (pixel (0, 0) is the
// centre of the top-left pixel), so pixel u covers [u - 0.5, u + 0.5) and the canvas draws it at
// (u + 0.5) * scale + offset.
export class Viewport {
  constructor() {
    this.scale = 1;
    this.ox = 0;
    this.oy = 0;
    this.minScale = 0.05;
    this.maxScale = 64;
  }

  fit(imageW, imageH, canvasW, canvasH, margin = 8) {
    const s = Math.min((canvasW - 2 * margin) / imageW, (canvasH - 2 * margin) / imageH);
    this.scale = Math.max(s, 1e-3);
    this.minScale = this.scale / 4;
    this.ox = (canvasW - imageW * this.scale) / 2;
    this.oy = (canvasH - imageH * this.scale) / 2;
    return this;
  }

  // Show the image rectangle [x0, x1] x [y0, y1] (image pixels) as large as it fits, centred.
  fitRect(x0, y0, x1, y1, canvasW, canvasH, margin = 0) {
    const w = Math.max(1, x1 - x0), hh = Math.max(1, y1 - y0);
    this.scale = Math.max(Math.min((canvasW - 2 * margin) / w, (canvasH - 2 * margin) / hh), 1e-3);
    this.minScale = this.scale / 8;
    this.ox = canvasW / 2 - ((x0 + x1) / 2 + 0.5) * this.scale;
    this.oy = canvasH / 2 - ((y0 + y1) / 2 + 0.5) * this.scale;
    return this;
  }

  // Pan so the image covers the canvas along each axis where it is larger than the canvas (no blank beyond its
  // edge), else centre it along that axis; the zoom stays.
  keepInside(imageW, imageH, canvasW, canvasH) {
    const fit = (o, size, room) => (size >= room ? Math.min(0, Math.max(room - size, o)) : (room - size) / 2);
    this.ox = fit(this.ox, imageW * this.scale, canvasW);
    this.oy = fit(this.oy, imageH * this.scale, canvasH);
    return this;
  }

  toScreen(u, v) {
    return [(u + 0.5) * this.scale + this.ox, (v + 0.5) * this.scale + this.oy];
  }

  toImage(x, y) {
    return [(x - this.ox) / this.scale - 0.5, (y - this.oy) / this.scale - 0.5];
  }

  // Zoom by `factor` keeping the screen point (x, y) fixed.
  zoomAt(factor, x, y) {
    const scale = Math.min(this.maxScale, Math.max(this.minScale, this.scale * factor));
    const k = scale / this.scale;
    this.ox = x - (x - this.ox) * k;
    this.oy = y - (y - this.oy) * k;
    this.scale = scale;
  }

  pan(dx, dy) {
    this.ox += dx;
    this.oy += dy;
  }

  // Canvas transform for drawing in image-canvas units (drawImage(image, 0, 0)), times devicePixelRatio.
  apply(ctx, dpr = 1) {
    ctx.setTransform(this.scale * dpr, 0, 0, this.scale * dpr, this.ox * dpr, this.oy * dpr);
  }
}
