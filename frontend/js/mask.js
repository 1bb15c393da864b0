// Hand masks in the browser: a bit per pixel, brush and eraser strokes, undo snapshots, the run-length
// encoding the API takes (row-major runs starting with background, backend/services/captures/masks.py), and an
// RGBA overlay canvas updated only where a stroke changed pixels (so a stroke stays cheap on 1280x1024).

export class MaskLayer {
  constructor(width, height, bits = null) {
    this.width = width;
    this.height = height;
    this.bits = bits || new Uint8Array(width * height);
    if (this.bits.length !== width * height) throw new Error(`mask has ${this.bits.length} pixels, not ${width}x${height}`);
  }

  static fromImageData(imageData) {
    const { width, height, data } = imageData;
    const bits = new Uint8Array(width * height);
    for (let i = 0, j = 0; i < bits.length; i++, j += 4) bits[i] = data[j] > 127 ? 1 : 0;
    return new MaskLayer(width, height, bits);
  }

  static fromRLE(counts, width, height) {
    const bits = new Uint8Array(width * height);
    let pos = 0, value = 0;
    for (const run of counts) {
      if (pos + run > bits.length) throw new Error("mask rle covers more pixels than the image");
      if (value) bits.fill(1, pos, pos + run);
      pos += run;
      value ^= 1;
    }
    if (pos !== bits.length) throw new Error(`mask rle covers ${pos} pixels, the image has ${bits.length}`);
    return new MaskLayer(width, height, bits);
  }

  toRLE() {
    const counts = [];
    const bits = this.bits;
    let value = 0, run = 0;
    for (let i = 0; i < bits.length; i++) {
      if (bits[i] !== value) {
        counts.push(run);
        value = bits[i];
        run = 0;
      }
      run++;
    }
    counts.push(run);
    return counts;
  }

  count() {
    let n = 0;
    for (let i = 0; i < this.bits.length; i++) n += this.bits[i];
    return n;
  }

  // Paint (value 1) or erase (0) every pixel whose centre lies within `radius` of the segment
  // (x0, y0)-(x1, y1), image pixels. Returns the changed bounding rect {x, y, w, h} or null.
  stroke(x0, y0, x1, y1, radius, value) {
    const W = this.width, H = this.height;
    const xa = Math.max(0, Math.floor(Math.min(x0, x1) - radius));
    const xb = Math.min(W - 1, Math.ceil(Math.max(x0, x1) + radius));
    const ya = Math.max(0, Math.floor(Math.min(y0, y1) - radius));
    const yb = Math.min(H - 1, Math.ceil(Math.max(y0, y1) + radius));
    if (xa > xb || ya > yb) return null;
    const dx = x1 - x0, dy = y1 - y0;
    const len2 = dx * dx + dy * dy;
    const r2 = radius * radius;
    const bits = this.bits;
    const v = value ? 1 : 0;
    for (let y = ya; y <= yb; y++) {
      const row = y * W;
      for (let x = xa; x <= xb; x++) {
        let t = len2 > 0 ? ((x - x0) * dx + (y - y0) * dy) / len2 : 0;
        t = t < 0 ? 0 : t > 1 ? 1 : t;
        const ex = x - (x0 + t * dx), ey = y - (y0 + t * dy);
        if (ex * ex + ey * ey <= r2) bits[row + x] = v;
      }
    }
    return { x: xa, y: ya, w: xb - xa + 1, h: yb - ya + 1 };
  }

  read(rect) {
    const out = new Uint8Array(rect.w * rect.h);
    for (let r = 0; r < rect.h; r++) {
      const start = (rect.y + r) * this.width + rect.x;
      out.set(this.bits.subarray(start, start + rect.w), r * rect.w);
    }
    return out;
  }

  write(rect, data) {
    for (let r = 0; r < rect.h; r++) {
      this.bits.set(data.subarray(r * rect.w, (r + 1) * rect.w), (rect.y + r) * this.width + rect.x);
    }
  }
}

export function unionRect(a, b) {
  if (!a) return b;
  if (!b) return a;
  const x = Math.min(a.x, b.x), y = Math.min(a.y, b.y);
  return { x, y, w: Math.max(a.x + a.w, b.x + b.w) - x, h: Math.max(a.y + a.h, b.y + b.h) - y };
}

// One stroke (pointer down .. up) of brush or eraser, as an undoable command: only the changed
// rectangle's pixels before and after are kept.
export class StrokeRecorder {
  constructor(layer) {
    this.layer = layer;
    this.before = layer.bits.slice();
    this.rect = null;
  }

  add(rect) {
    this.rect = unionRect(this.rect, rect);
  }

  finish(onApply) {
    if (!this.rect) return null;
    const rect = this.rect, layer = this.layer;
    const before = new MaskLayer(layer.width, layer.height, this.before).read(rect);
    const after = layer.read(rect);
    this.before = null;
    return {
      rect,
      undo() { layer.write(rect, before); onApply(rect); },
      redo() { layer.write(rect, after); onApply(rect); },
    };
  }
}

function makeCanvas(width, height) {
  if (typeof OffscreenCanvas !== "undefined") return new OffscreenCanvas(width, height);
  const canvas = document.createElement("canvas");
  canvas.width = width;
  canvas.height = height;
  return canvas;
}

// The mask drawn as a translucent colour over the image; refresh(rect) re-uploads a rectangle only.
export class MaskOverlay {
  constructor(layer, rgba = [0, 140, 255, 80]) {
    this.layer = layer;
    this.canvas = makeCanvas(layer.width, layer.height);
    this.ctx = this.canvas.getContext("2d");
    this.image = this.ctx.createImageData(layer.width, layer.height);
    this.pixels = new Uint32Array(this.image.data.buffer);
    const little = new Uint8Array(new Uint32Array([1]).buffer)[0] === 1;
    const [r, g, b, a] = rgba;
    this.on = little ? ((a << 24) | (b << 16) | (g << 8) | r) >>> 0 : ((r << 24) | (g << 16) | (b << 8) | a) >>> 0;
    this.refresh({ x: 0, y: 0, w: layer.width, h: layer.height });
  }

  // The mask's boundary only (pixels inside with a 4-neighbour outside), opaque: drawn in points mode, so
  // the skin under the mask stays visible where the fingertips are placed. Rebuilt after a change.
  outline() {
    if (this.outlineCanvas && !this.outlineStale) return this.outlineCanvas;
    const { width, height, bits } = this.layer;
    if (!this.outlineCanvas) {
      this.outlineCanvas = makeCanvas(width, height);
      this.outlineImage = this.outlineCanvas.getContext("2d").createImageData(width, height);
    }
    const px = new Uint32Array(this.outlineImage.data.buffer);
    const little = new Uint8Array(new Uint32Array([1]).buffer)[0] === 1;
    const edge = little ? 0xff00e5ff : 0xffe500ff; // opaque yellow (#ffe500)
    px.fill(0);
    for (let y = 0; y < height; y++) {
      for (let x = 0, i = y * width; x < width; x++, i++) {
        if (!bits[i]) continue;
        if (x === 0 || y === 0 || x === width - 1 || y === height - 1 || !bits[i - 1] || !bits[i + 1] ||
            !bits[i - width] || !bits[i + width]) px[i] = edge;
      }
    }
    this.outlineCanvas.getContext("2d").putImageData(this.outlineImage, 0, 0);
    this.outlineStale = false;
    return this.outlineCanvas;
  }

  // The mask's bounding box in image pixels [x0, y0, x1, y1], or null when it is empty.
  bounds() {
    const { width, height, bits } = this.layer;
    let x0 = width, y0 = height, x1 = -1, y1 = -1;
    for (let y = 0; y < height; y++) {
      for (let x = 0, i = y * width; x < width; x++, i++) {
        if (!bits[i]) continue;
        if (x < x0) x0 = x;
        if (x > x1) x1 = x;
        if (y < y0) y0 = y;
        y1 = y;
      }
    }
    return x1 < 0 ? null : [x0, y0, x1, y1];
  }

  refresh(rect) {
    this.outlineStale = true;
    const { width } = this.layer;
    const bits = this.layer.bits, pixels = this.pixels, on = this.on;
    for (let y = rect.y; y < rect.y + rect.h; y++) {
      for (let i = y * width + rect.x, end = i + rect.w; i < end; i++) pixels[i] = bits[i] ? on : 0;
    }
    this.ctx.putImageData(this.image, 0, 0, rect.x, rect.y, rect.w, rect.h);
  }
}
