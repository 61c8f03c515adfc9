//! The few shapes drawn every frame, rasterised directly: rectangles in
//! their own frame (a car's body, windscreen and brake lights; a rain
//! streak; a snowflake) placed on the canvas by an affine map, and convex
//! quadrilaterals (headlight beams).
//!
//! Each row of pixels meets such a shape in one span of pixel centres,
//! found from the row's centre line, so a shape costs its rows and its edge
//! pixels, not its bounding box: the inside is stored whole, and only the
//! pixels within half a pixel of an edge get a coverage.
//!
//! - Anti-aliased fills weigh a colour by the pixel's box-filtered overlap
//!   along each of the rectangle's two axes (exact for an axis-aligned
//!   rectangle, and within a few levels of the true area when turned).
//! - Hard-edged fills and the instance mask take exactly the pixels whose
//!   centres lie inside (edges included).
//!
//! They draw straight into a frame's RGB rows ([`RgbImage`]), whose pixels
//! are opaque, so blending a colour with alpha `a` is
//! `(colour a + dst (255 - a)) / 255`, rounded.

use tiny_skia::Transform;

/// An opaque RGB image being drawn on: `height` rows of `width` pixels, 3
/// bytes each, borrowed from the frame that owns them.
pub struct RgbImage<'a> {
    pub data: &'a mut [u8],
    pub width: usize,
    pub height: usize,
}

impl<'a> RgbImage<'a> {
    /// `data` as `width` x `height` RGB pixels; `None` when the sizes
    /// disagree.
    pub fn new(data: &'a mut [u8], width: usize, height: usize) -> Option<RgbImage<'a>> {
        (data.len() == width * height * 3).then_some(RgbImage { data, width, height })
    }

    /// The pixels `x0..x1` of row `y`, 3 bytes each.
    fn span_mut(&mut self, y: usize, (x0, x1): Span) -> &mut [u8] {
        let row = y * self.width;
        &mut self.data[(row + x0) * 3..(row + x1) * 3]
    }
}

/// A rectangle `[x0, x1] x [y0, y1]` of a shape's own frame, and where that
/// frame lies on the canvas.
#[derive(Debug, Clone, Copy)]
pub struct PlacedRect {
    /// Canvas pixels to the shape's frame: `(sx, kx, tx, ky, sy, ty)` with
    /// `u = sx x + kx y + tx`, `v = ky x + sy y + ty`.
    to_shape: [f32; 6],
    /// Canvas pixels per unit of the shape's frame (the map is a similarity).
    pixels_per_unit: f32,
    x: (f32, f32),
    y: (f32, f32),
}

/// A span of pixel columns `x0..x1` in one row.
type Span = (usize, usize);

impl PlacedRect {
    /// The rectangle `x` by `y` of the frame that `to_canvas` maps onto the
    /// canvas (a rotation, uniform scale, mirror and shift); `None` when the
    /// map is degenerate.
    pub fn new(to_canvas: Transform, x: (f32, f32), y: (f32, f32)) -> Option<PlacedRect> {
        let inverse = to_canvas.invert()?;
        let det = to_canvas.sx * to_canvas.sy - to_canvas.kx * to_canvas.ky;
        let pixels_per_unit = det.abs().sqrt();
        (pixels_per_unit.is_finite() && pixels_per_unit > 0.0).then_some(PlacedRect {
            to_shape: [inverse.sx, inverse.kx, inverse.tx, inverse.ky, inverse.sy, inverse.ty],
            pixels_per_unit,
            x,
            y,
        })
    }

    /// The columns of row `row` (clipped to `0..width`) whose pixel centres
    /// lie in the rectangle grown by `grow` units on every side (shrunk when
    /// negative); `None` when there are none.
    fn span(&self, row: usize, grow: f32, width: usize) -> Option<Span> {
        let yc = row as f32 + 0.5;
        let [sx, kx, tx, ky, sy, ty] = self.to_shape;
        let (mut lo, mut hi) = (f32::NEG_INFINITY, f32::INFINITY);
        for (slope, at_zero, (a, b)) in [(sx, kx * yc + tx, self.x), (ky, sy * yc + ty, self.y)] {
            let (a, b) = (a - grow, b + grow);
            if a > b {
                return None;
            }
            if slope == 0.0 {
                if at_zero < a || at_zero > b {
                    return None;
                }
                continue;
            }
            let (t1, t2) = ((a - at_zero) / slope, (b - at_zero) / slope);
            lo = lo.max(t1.min(t2));
            hi = hi.min(t1.max(t2));
        }
        as_span(centres_within(lo, hi, width))
    }

    /// [`PlacedRect::span`] for many rows at one `grow`, with what does not
    /// depend on the row worked out once (a car's body or a rain streak asks
    /// for a span on each of its rows, thousands a frame).
    fn scan(&self, grow: f32) -> RowScan {
        let [sx, kx, tx, ky, sy, ty] = self.to_shape;
        let (x, y) = ((self.x.0 - grow, self.x.1 + grow), (self.y.0 - grow, self.y.1 + grow));
        let finite = self.to_shape.iter().chain([&x.0, &x.1, &y.0, &y.1]).all(|v| v.is_finite());
        // Where neither slope is 0 and every term is finite, no quotient is
        // NaN, so each slab's lower bound is the quotient of its lower end
        // (the upper end when the slope is negative: division by a
        // negative number reverses the order and rounding keeps it) and
        // `min` and `max` are plain comparisons: the same bounds as `span`.
        // A slab whose slope is 0 bounds no column: it lets a row through
        // or not (an upright rectangle, such as a snowflake or a car
        // heading due east, has one).
        if !(finite && x.0 <= x.1 && y.0 <= y.1) {
            return RowScan::General { rect: *self, grow };
        }
        let ends = |slope: f32, (a, b): (f32, f32)| if slope > 0.0 { (a, b) } else { (b, a) };
        let ((x_lo, x_hi), (y_lo, y_hi)) = (ends(sx, x), ends(ky, y));
        match (sx != 0.0, ky != 0.0) {
            (true, true) => RowScan::Turned {
                slopes: [sx, ky],
                row_terms: [kx, sy],
                offsets: [tx, ty],
                lower: [x_lo, y_lo],
                upper: [x_hi, y_hi],
            },
            (true, false) => {
                RowScan::Gated { slope: sx, row_term: kx, offset: tx, ends: (x_lo, x_hi), gate: (sy, ty, y) }
            }
            (false, true) => {
                RowScan::Gated { slope: ky, row_term: sy, offset: ty, ends: (y_lo, y_hi), gate: (kx, tx, x) }
            }
            (false, false) => RowScan::General { rect: *self, grow },
        }
    }

    /// [`PlacedRect::span`] kept out of line, so that the row scan's common
    /// cases inline into the fills.
    #[cold]
    #[inline(never)]
    fn span_cold(&self, row: usize, grow: f32, width: usize) -> Option<Span> {
        self.span(row, grow, width)
    }

    /// The rows (clipped to `0..height`) the rectangle grown by `grow` can
    /// reach.
    fn rows(&self, grow: f32, height: usize) -> std::ops::Range<usize> {
        let [sx, kx, tx, ky, sy, ty] = self.to_shape;
        // Back to the canvas: the inverse of the inverse, from its corners.
        let det = sx * sy - kx * ky;
        if det == 0.0 || !det.is_finite() {
            return 0..0;
        }
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for u in [self.x.0 - grow, self.x.1 + grow] {
            for v in [self.y.0 - grow, self.y.1 + grow] {
                // Solve sx x + kx y = u - tx, ky x + sy y = v - ty for y.
                let y = (sx * (v - ty) - ky * (u - tx)) / det;
                lo = lo.min(y);
                hi = hi.max(y);
            }
        }
        if !(lo.is_finite() && hi.is_finite()) {
            return 0..0;
        }
        centres_within(lo, hi, height)
    }

    /// The box-filtered coverage (0 to 255) of the pixel at column `x` of
    /// row `y`, for each `x`, from the shape-frame point at the pixel's
    /// centre (`u = sx x + kx y + tx`, `v = ky x + sy y + ty`), with the
    /// row's products worked out once.
    fn coverage_in_row(&self, y: usize) -> impl Fn(usize) -> u8 + '_ {
        let [sx, kx, tx, ky, sy, ty] = self.to_shape;
        let py = y as u32 as f32 + 0.5;
        let (kx_py, sy_py) = (kx * py, sy * py);
        let s = self.pixels_per_unit;
        let along = move |p: f32, (a, b): (f32, f32)| ((p - a) * s).min(0.5) + ((b - p) * s).min(0.5);
        move |x| {
            let px = x as u32 as f32 + 0.5;
            let (u, v) = (sx * px + kx_py + tx, ky * px + sy_py + ty);
            let c = along(u, self.x).clamp(0.0, 1.0) * along(v, self.y).clamp(0.0, 1.0);
            (c * 255.0 + 0.5) as u8
        }
    }
}

/// The spans of a [`PlacedRect`] grown by a fixed amount, row after row:
/// the same spans as [`PlacedRect::span`], found with four divisions and no
/// branch per row where the rectangle is turned (neither of its axes runs
/// along the rows), two where it is upright, and by `span` itself where a
/// term is not finite, the grown rectangle is empty or both slopes are 0.
#[derive(Debug, Clone, Copy)]
enum RowScan {
    Turned {
        /// Each slab's change in shape coordinate per canvas column (`sx`, `ky`).
        slopes: [f32; 2],
        /// Each slab's change per canvas row (`kx`, `sy`) and its offset (`tx`, `ty`).
        row_terms: [f32; 2],
        offsets: [f32; 2],
        /// The slab's end that bounds the columns from below, and from above.
        lower: [f32; 2],
        upper: [f32; 2],
    },
    /// One slab bounds the columns, the other (slope 0) admits whole rows.
    Gated {
        slope: f32,
        row_term: f32,
        offset: f32,
        /// The bounding slab's ends, lower bound first.
        ends: (f32, f32),
        /// The admitting slab's change per row, offset and ends.
        gate: (f32, f32, (f32, f32)),
    },
    General {
        rect: PlacedRect,
        grow: f32,
    },
}

impl RowScan {
    /// The columns of row `row` (clipped to `0..width`) whose pixel centres
    /// lie in the grown rectangle; `None` when there are none.
    #[inline(always)]
    fn span(&self, row: usize, width: usize) -> Option<Span> {
        match *self {
            RowScan::Turned { slopes, row_terms, offsets, lower, upper } => {
                let yc = row as f32 + 0.5;
                let at_zero = [row_terms[0] * yc + offsets[0], row_terms[1] * yc + offsets[1]];
                let quotient = |end: [f32; 2], k: usize| (end[k] - at_zero[k]) / slopes[k];
                let (lo0, lo1, hi0, hi1) =
                    (quotient(lower, 0), quotient(lower, 1), quotient(upper, 0), quotient(upper, 1));
                let lo = if lo1 > lo0 { lo1 } else { lo0 };
                let hi = if hi1 < hi0 { hi1 } else { hi0 };
                as_span(centres_within(lo, hi, width))
            }
            RowScan::Gated { slope, row_term, offset, ends, gate: (gate_row_term, gate_offset, (a, b)) } => {
                let yc = row as f32 + 0.5;
                let gated = gate_row_term * yc + gate_offset;
                if gated < a || gated > b {
                    return None;
                }
                let at_zero = row_term * yc + offset;
                as_span(centres_within((ends.0 - at_zero) / slope, (ends.1 - at_zero) / slope, width))
            }
            RowScan::General { rect, grow } => rect.span_cold(row, grow, width),
        }
    }
}

/// A convex quadrilateral given by its corners on the canvas (pixels, in
/// order around it, either way).
#[derive(Debug, Clone, Copy)]
pub struct ConvexQuad {
    corners: [(f32, f32); 4],
    /// 1 when the corners run counter-clockwise in the canvas's axes, -1
    /// when clockwise.
    turn: f32,
    /// Each edge's terms that do not depend on the row (see `span`).
    edges: [QuadEdge; 4],
}

/// An edge from corner `a` to corner `b` of a [`ConvexQuad`]: a point `p` is
/// inside when `turn * cross(b - a, p - a) >= 0`, which along row `yc` is
/// `slope * x + (dx * (yc - ay) + c) * turn >= 0`.
#[derive(Debug, Clone, Copy)]
struct QuadEdge {
    ay: f32,
    /// `bx - ax`.
    dx: f32,
    /// `(by - ay) * ax`.
    c: f32,
    /// `-(by - ay) * turn`.
    slope: f32,
}

impl ConvexQuad {
    /// The quadrilateral with these corners; `None` when they are not finite
    /// or enclose no area.
    pub fn new(corners: [(f32, f32); 4]) -> Option<ConvexQuad> {
        let area: f32 = (0..4)
            .map(|i| {
                let ((x0, y0), (x1, y1)) = (corners[i], corners[(i + 1) % 4]);
                x0 * y1 - x1 * y0
            })
            .sum();
        let turn = area.signum();
        let edges = std::array::from_fn(|i| {
            let ((ax, ay), (bx, by)) = (corners[i], corners[(i + 1) % 4]);
            QuadEdge { ay, dx: bx - ax, c: (by - ay) * ax, slope: -(by - ay) * turn }
        });
        (area.is_finite() && area != 0.0).then_some(ConvexQuad { corners, turn, edges })
    }

    /// The rows (clipped to `0..height`) whose centre line it crosses.
    fn rows(&self, height: usize) -> std::ops::Range<usize> {
        let lo = self.corners.iter().map(|c| c.1).fold(f32::INFINITY, f32::min);
        let hi = self.corners.iter().map(|c| c.1).fold(f32::NEG_INFINITY, f32::max);
        centres_within(lo, hi, height)
    }

    /// The columns of row `row` (clipped to `0..width`) whose pixel centres
    /// lie inside, edges included.
    fn span(&self, row: usize, width: usize) -> Option<Span> {
        let yc = row as f32 + 0.5;
        let (mut lo, mut hi) = (f32::NEG_INFINITY, f32::INFINITY);
        let turn = self.turn;
        for &QuadEdge { ay, dx, c, slope } in &self.edges {
            // Inside: turn * cross(b - a, p - a) >= 0, linear in p's x.
            let at_zero = (dx * (yc - ay) + c) * turn;
            if slope == 0.0 {
                if at_zero < 0.0 {
                    return None;
                }
            } else if slope > 0.0 {
                lo = lo.max(-at_zero / slope);
            } else {
                hi = hi.min(-at_zero / slope);
            }
        }
        as_span(centres_within(lo, hi, width))
    }
}

/// The pixels of `0..limit` whose centres (pixel `i`'s at `i + 0.5`) lie in
/// `[lo, hi]`; empty when none do or `hi` is NaN (a NaN `lo` bounds
/// nothing; callers' bounds, by `min` and `max` or by comparisons of
/// values that cannot be NaN, never give one).
fn centres_within(lo: f32, hi: f32, limit: usize) -> std::ops::Range<usize> {
    let first = ceil_within(lo - 0.5, limit);
    let end = if hi - 0.5 >= 0.0 { (floor_within(hi - 0.5, limit) + 1).min(limit) } else { 0 };
    first.min(end)..end
}

/// `v.ceil().clamp(0, limit)` as an index (0 for NaN; for limits below
/// 2^24, exactly, and for any an image can have), from integer
/// truncation: the target's baseline has no rounding instruction, so `ceil`
/// and `floor` are calls, and rows and spans need millions a run.
pub(crate) fn ceil_within(v: f32, limit: usize) -> usize {
    let v = if v > 0.0 { v.min(limit_f32(limit)) } else { 0.0 };
    let t = v as u32;
    t as usize + ((t as f32) < v) as usize
}

/// `v.floor().clamp(0, limit)` as an index (0 for NaN).
pub(crate) fn floor_within(v: f32, limit: usize) -> usize {
    if v > 0.0 {
        v.min(limit_f32(limit)) as u32 as usize
    } else {
        0
    }
}

/// `limit` as an `f32`, through `u32`: `usize` to `f32` and back take a
/// branch each for the top bit, which no image's size has (limits above
/// `u32::MAX` count as `u32::MAX`).
fn limit_f32(limit: usize) -> f32 {
    limit.min(u32::MAX as usize) as u32 as f32
}

/// A non-empty range as a span.
fn as_span(columns: std::ops::Range<usize>) -> Option<Span> {
    (!columns.is_empty()).then_some((columns.start, columns.end))
}

/// Blends `colour` at alpha `alpha` once into every pixel whose centre lies
/// in either of `pair` (hard edges; where they overlap, the light is not
/// doubled).
pub fn fill_hard_union(image: &mut RgbImage, pair: [Option<ConvexQuad>; 2], colour: [u8; 3], alpha: u8) {
    let (w, h) = (image.width, image.height);
    let rows = pair.iter().flatten().map(|q| q.rows(h)).filter(|r| !r.is_empty());
    let (first, last) = rows.fold((usize::MAX, 0), |(a, b), r| (a.min(r.start), b.max(r.end)));
    let [a, b] = pair;
    let light = SpanBlend::new(colour, alpha);
    for y in first..last {
        match (a.and_then(|q| q.span(y, w)), b.and_then(|q| q.span(y, w))) {
            (Some(one), Some(other)) => {
                // Left to right; the second from where the first ended.
                let (first, second) = if one <= other { (one, other) } else { (other, one) };
                light.blend(image.span_mut(y, first));
                light.blend(image.span_mut(y, (second.0.max(first.1), second.1.max(first.1))));
            }
            (Some(only), None) | (None, Some(only)) => light.blend(image.span_mut(y, only)),
            (None, None) => {}
        }
    }
}

/// `colour` at alpha `a` over the opaque RGB pixel `dst`.
fn blend(dst: &mut [u8], colour: [u8; 3], a: u8) {
    let (terms, keep) = (blend_terms(colour, a), 255 - a as u32);
    for k in 0..3 {
        dst[k] = blend_byte(terms[k], dst[k], keep);
    }
}

/// [`blend`] over every pixel of `span` (RGB bytes): 16 pixels at a time
/// through one pattern of the colour's terms, which the compiler turns into
/// vector arithmetic (a beam blends thousands of pixels a frame).
fn blend_span(span: &mut [u8], colour: [u8; 3], a: u8) {
    if span.len() < 48 {
        // A rain streak's few pixels: building the pattern costs more.
        let (terms, keep) = (blend_terms(colour, a), 255 - a as u32);
        for px in span.chunks_exact_mut(3) {
            for k in 0..3 {
                px[k] = blend_byte(terms[k], px[k], keep);
            }
        }
        return;
    }
    SpanBlend::new(colour, a).blend(span);
}

/// `colour`'s terms at alpha `a` (out of 255): `colour * a + 127` per
/// channel, the part of a blend that does not depend on the pixel.
#[inline(always)]
fn blend_terms(colour: [u8; 3], a: u8) -> [u32; 3] {
    colour.map(|c| c as u32 * a as u32 + 127)
}

/// Byte `d` under a colour's `term` ([`blend_terms`]), `keep` = 255 - a:
/// `(colour * a + d * (255 - a) + 127) / 255`.
#[inline(always)]
fn blend_byte(term: u32, d: u8, keep: u32) -> u8 {
    ((term + d as u32 * keep) / 255) as u8
}

/// `colour` at one alpha, ready to blend over many spans (a headlight
/// beam's rows): [`blend_span`]'s pattern built once.
struct SpanBlend {
    keep: u32,
    /// The colour's terms, `colour * a + 127`, for 16 pixels.
    pattern: [u32; 48],
}

impl SpanBlend {
    fn new(colour: [u8; 3], a: u8) -> SpanBlend {
        let terms = blend_terms(colour, a);
        SpanBlend { keep: 255 - a as u32, pattern: std::array::from_fn(|i| terms[i % 3]) }
    }

    /// Blends over every pixel of `span` (RGB bytes).
    fn blend(&self, span: &mut [u8]) {
        let (keep, pattern) = (self.keep, &self.pattern);
        let mut chunks = span.chunks_exact_mut(48);
        for chunk in &mut chunks {
            for (d, &t) in chunk.iter_mut().zip(pattern) {
                *d = blend_byte(t, *d, keep);
            }
        }
        for (d, &t) in chunks.into_remainder().iter_mut().zip(pattern) {
            *d = blend_byte(t, *d, keep);
        }
    }
}

/// Sets every pixel of `span` (RGB bytes) to `colour`: 16 pixels at a time
/// from one pattern, as a car's row is mostly inside.
fn fill_span(span: &mut [u8], colour: [u8; 3]) {
    let pattern: [u8; 48] = std::array::from_fn(|i| colour[i % 3]);
    let mut chunks = span.chunks_exact_mut(48);
    for chunk in &mut chunks {
        chunk.copy_from_slice(&pattern);
    }
    let rest = chunks.into_remainder();
    let n = rest.len();
    copy_short(rest, &pattern[..n]);
}

/// Fills `rect` with the opaque `colour`, anti-aliased.
pub fn fill_aa(image: &mut RgbImage, rect: &PlacedRect, colour: [u8; 3]) {
    let (w, h) = (image.width, image.height);
    let half_pixel = 0.5 / rect.pixels_per_unit;
    let (outer, inner) = (rect.scan(half_pixel), rect.scan(-half_pixel));
    for y in rect.rows(half_pixel, h) {
        let Some((x0, x1)) = outer.span(y, w) else { continue };
        let (i0, i1) = inner.span(y, w).map_or((x1, x1), |(a, b)| (a.max(x0), b.min(x1).max(a.max(x0))));
        let row = image.span_mut(y, (0, w));
        let coverage = rect.coverage_in_row(y);
        for x in (x0..i0).chain(i1..x1) {
            let a = coverage(x);
            if a > 0 {
                blend(&mut row[x * 3..x * 3 + 3], colour, a);
            }
        }
        fill_span(&mut row[i0 * 3..i1 * 3], colour);
    }
}

/// Blends `colour` at alpha `alpha` into every pixel whose centre lies in
/// `rect` (hard edges), first saving those pixels in `undo` when given.
pub fn fill_hard(image: &mut RgbImage, rect: &PlacedRect, colour: [u8; 3], alpha: u8, mut undo: Option<&mut Undo>) {
    let scan = rect.scan(0.0);
    for y in rect.rows(0.0, image.height) {
        if let Some(span) = scan.span(y, image.width) {
            if let Some(undo) = undo.as_deref_mut() {
                undo.save(image, y, span);
            }
            blend_span(image.span_mut(y, span), colour, alpha);
        }
    }
}

/// `to.copy_from_slice(from)` for the short rows that most shapes touch
/// (a snowflake's or a rain streak's are a few pixels): in place, 8 bytes
/// at a time, or as two overlapping fixed-size copies below 8 bytes, as a
/// call to `memcpy` for every row costs more than the copying (over a
/// million calls in 1,200 rainy frames).
pub(crate) fn copy_short(to: &mut [u8], from: &[u8]) {
    let n = from.len();
    assert_eq!(to.len(), n, "copy between rows of one length");
    if n >= 64 {
        to.copy_from_slice(from);
    } else if n >= 8 {
        for (t, f) in to.chunks_exact_mut(8).zip(from.chunks_exact(8)) {
            t.copy_from_slice(f);
        }
        // The last 8 bytes again covers the rest, whatever the length.
        to[n - 8..].copy_from_slice(&from[n - 8..]);
    } else if n >= 4 {
        // Two 4-byte copies that overlap (a loop here became a `memcpy`
        // call: a pixel or two of a streak's row is the common case).
        to[..4].copy_from_slice(&from[..4]);
        to[n - 4..].copy_from_slice(&from[n - 4..]);
    } else if n >= 2 {
        to[..2].copy_from_slice(&from[..2]);
        to[n - 2..].copy_from_slice(&from[n - 2..]);
    } else if n == 1 {
        to[0] = from[0];
    }
}

/// Pixels of an [`RgbImage`] as they were before shapes were drawn over
/// them, to put back: what a frame's rain and snow covered, restored at the
/// next frame from this short log instead of from the still layer, row by
/// row of every streak's box.
#[derive(Debug, Default)]
pub struct Undo {
    /// The saved bytes, span after span, in `bytes[..used]`. The buffer
    /// keeps its length between frames (what lies past `used` is stale), so
    /// saving a streak's row of a few bytes neither zeroes nor allocates.
    bytes: Vec<u8>,
    used: usize,
    /// Where each span came from: its first byte in the image, its length.
    spans: Vec<(usize, usize)>,
}

impl Undo {
    /// Saves the pixels `span` of row `y` before they change.
    fn save(&mut self, image: &RgbImage, y: usize, (x0, x1): Span) {
        let start = (y * image.width + x0) * 3;
        let len = (x1 - x0) * 3;
        self.spans.push((start, len));
        let (at, end) = (self.used, self.used + len);
        if end > self.bytes.len() {
            self.bytes.resize((2 * end).max(4096), 0);
        }
        copy_short(&mut self.bytes[at..end], &image.data[start..start + len]);
        self.used = end;
    }

    /// Puts every saved pixel back into `data`, the last saved first (so
    /// overlapping shapes unwind in order), and forgets them.
    pub fn restore(&mut self, data: &mut [u8]) {
        let mut end = self.used;
        for &(start, len) in self.spans.iter().rev() {
            copy_short(&mut data[start..start + len], &self.bytes[end - len..end]);
            end -= len;
        }
        self.clear();
    }

    /// Forgets every saved pixel (the image was redrawn whole).
    pub fn clear(&mut self) {
        self.used = 0;
        self.spans.clear();
    }

    /// Whether no pixel is saved.
    #[cfg(test)]
    fn is_empty(&self) -> bool {
        self.used == 0 && self.spans.is_empty()
    }
}

/// Writes `id` into the row-major `width`-wide `mask` at every pixel whose
/// centre lies in `rect` (no anti-aliasing).
pub fn stamp(mask: &mut [u8], width: usize, rect: &PlacedRect, id: u8) {
    let height = mask.len() / width.max(1);
    let scan = rect.scan(0.0);
    for y in rect.rows(0.0, height) {
        if let Some((x0, x1)) = scan.span(y, width) {
            mask[y * width + x0..y * width + x1].fill(id);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An RGB canvas of one colour, (10, 20, 30).
    struct Canvas {
        data: Vec<u8>,
        width: usize,
    }

    impl Canvas {
        fn image(&mut self) -> RgbImage<'_> {
            let height = self.data.len() / 3 / self.width;
            RgbImage::new(&mut self.data, self.width, height).unwrap()
        }

        fn red(&self, x: usize, y: usize) -> u8 {
            self.data[(y * self.width + x) * 3]
        }
    }

    fn canvas(width: usize, height: usize) -> Canvas {
        Canvas { data: [10, 20, 30].repeat(width * height), width }
    }

    #[test]
    fn pixel_ranges_are_ceil_and_floor_clamped() {
        let reference = |lo: f32, hi: f32, limit: usize| {
            let first = (lo - 0.5).ceil().clamp(0.0, limit as f32) as usize;
            let end = ((hi - 0.5).floor() + 1.0).clamp(0.0, limit as f32) as usize;
            first.min(end)..end
        };
        let mut values = vec![f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -3.0, -0.5, 0.0, 1e9];
        values.extend((-40..120).map(|i| i as f32 * 0.25 - 0.01 * (i % 3) as f32));
        let mut checked = 0;
        for &lo in &values {
            for &hi in &values {
                for limit in [0, 1, 7, 20] {
                    assert_eq!(centres_within(lo, hi, limit), reference(lo, hi, limit), "{lo} {hi} {limit}");
                    let clamped = |v: f32| v.clamp(0.0, limit as f32) as usize;
                    assert_eq!(ceil_within(lo, limit), clamped(lo.ceil()), "ceil {lo} {limit}");
                    assert_eq!(floor_within(lo, limit), clamped(lo.floor()), "floor {lo} {limit}");
                    checked += 1;
                }
            }
        }
        assert!(checked > 10_000);
    }

    #[test]
    fn a_row_scan_finds_the_spans_that_span_finds() {
        // Turned, axis-aligned, mirrored, tiny, huge, off the canvas and
        // empty rectangles, grown and shrunk, on every row they reach.
        let mut checked = 0;
        let mut filled = 0;
        for k in 0..400u32 {
            let angle = k as f32 * 0.37 + if k % 7 == 0 { 0.0 } else { 0.013 };
            let scale = [0.05, 1.0, 3.7, 40.0][k as usize % 4];
            // Every third one upright: a quarter turn, exactly.
            let (c, s) = match k % 3 {
                0 => [(1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0)][(k / 3) as usize % 4],
                _ => (angle.cos(), angle.sin()),
            };
            let (c, s) = (c * scale, s * scale);
            let mirror = if k % 5 == 0 { -1.0 } else { 1.0 };
            let shift = ((k * 37 % 90) as f32 - 15.0 + 0.25 * (k % 3) as f32, (k * 53 % 70) as f32 - 10.0);
            let to_canvas = Transform::from_row(c, s, -s * mirror, c * mirror, shift.0, shift.1);
            let half = (0.3 + (k % 9) as f32 * 0.45, 0.1 + (k % 4) as f32 * 0.3);
            let Some(rect) = PlacedRect::new(to_canvas, (-half.0, half.0), (-half.1 * 0.5, half.1)) else { continue };
            for grow in [0.0, 0.5 / rect.pixels_per_unit, -0.5 / rect.pixels_per_unit, -3.0] {
                let scan = rect.scan(grow);
                for row in 0..100 {
                    let expected = rect.span(row, grow, 80);
                    assert_eq!(scan.span(row, 80), expected, "rectangle {k}, grow {grow}, row {row}");
                    checked += 1;
                    filled += expected.is_some() as usize;
                }
            }
        }
        assert!(checked > 100_000 && filled > 10_000, "{checked} rows checked, {filled} with a span");
    }

    #[test]
    fn short_copies_copy_every_byte() {
        // Every length through each branch (1, 2-3, 4-7, 8-63, 64 and up),
        // from distinct non-zero bytes onto zeros.
        for n in 0..80 {
            let from: Vec<u8> = (0..n).map(|i| (i * 3 + 1) as u8).collect();
            let mut to = vec![0u8; n];
            copy_short(&mut to, &from);
            assert_eq!(to, from, "{n} bytes");
        }
    }

    #[test]
    fn a_span_blends_as_its_pixels_one_by_one() {
        for pixels in [0, 1, 15, 16, 17, 40] {
            for alpha in [0, 1, 120, 254, 255] {
                let original: Vec<u8> = (0..pixels * 3).map(|i| (i * 37 % 256) as u8).collect();
                let mut one_by_one = original.clone();
                for px in one_by_one.chunks_exact_mut(3) {
                    blend(px, [250, 7, 128], alpha);
                }
                let mut span = original.clone();
                blend_span(&mut span, [250, 7, 128], alpha);
                assert_eq!(span, one_by_one, "{pixels} pixels at alpha {alpha}");
                assert!(pixels == 0 || alpha == 0 || span != original, "nothing blended");
            }
        }
    }

    #[test]
    fn an_axis_aligned_rectangle_covers_its_exact_area() {
        // 3.25 x 2.5 pixels from (1.5, 2.25): whole pixels inside, a
        // quarter, half or three quarters on its edges.
        let rect = PlacedRect::new(Transform::identity(), (1.5, 4.75), (2.25, 4.75)).unwrap();
        let mut p = canvas(8, 8);
        fill_aa(&mut p.image(), &rect, [250, 20, 30]);
        let red = |x: usize, y: usize| p.red(x, y) as i32;
        let expect = |cover: f32| (250.0 * cover + 10.0 * (1.0 - cover)).round() as i32;
        assert_eq!(red(2, 3), 250, "inside");
        assert_eq!(red(0, 3), 10, "outside");
        assert!((red(1, 3) - expect(0.5)).abs() <= 1, "left edge half covered: {}", red(1, 3));
        assert!((red(4, 3) - expect(0.75)).abs() <= 1, "right edge: {}", red(4, 3));
        assert!((red(2, 2) - expect(0.75)).abs() <= 1, "top edge: {}", red(2, 2));
        assert!((red(1, 2) - expect(0.375)).abs() <= 1, "corner: {}", red(1, 2));
        let total: f32 =
            (0..8).flat_map(|y| (0..8).map(move |x| (x, y))).map(|(x, y)| (red(x, y) - 10) as f32 / 240.0).sum();
        assert!((total - 3.25 * 2.5).abs() < 0.05, "area {total}");
    }

    #[test]
    fn a_turned_rectangle_keeps_its_area_and_its_mask_is_its_pixel_centres() {
        let angle: f32 = 0.61;
        let to_canvas =
            Transform::from_row(angle.cos(), angle.sin(), -angle.sin(), angle.cos(), 20.3, 17.8).pre_scale(3.0, 3.0);
        let (hl, hw) = (4.0, 1.5);
        let rect = PlacedRect::new(to_canvas, (-hl, hl), (-hw, hw)).unwrap();
        let mut p = canvas(40, 40);
        fill_aa(&mut p.image(), &rect, [250, 20, 30]);
        let mut mask = vec![0u8; 40 * 40];
        stamp(&mut mask, 40, &rect, 7);
        let inverse = to_canvas.invert().unwrap();
        let mut area = 0.0;
        let mut checked = 0;
        for y in 0..40 {
            for x in 0..40 {
                area += (p.red(x, y) as f32 - 10.0) / 240.0;
                let mut c = [tiny_skia::Point::from_xy(x as f32 + 0.5, y as f32 + 0.5)];
                inverse.map_points(&mut c);
                let inside = c[0].x.abs() <= hl && c[0].y.abs() <= hw;
                let margin = (hl - c[0].x.abs()).min(hw - c[0].y.abs());
                if margin.abs() > 1e-3 {
                    assert_eq!(mask[y * 40 + x] == 7, inside, "pixel ({x}, {y})");
                    checked += 1;
                }
            }
        }
        assert!(checked > 1000);
        let expected = (2.0 * hl * 3.0) * (2.0 * hw * 3.0);
        assert!((area - expected).abs() < expected * 0.01, "area {area} vs {expected}");
    }

    #[test]
    fn overlapping_quads_light_each_pixel_once_and_only_inside() {
        // Two overlapping diamonds, one clockwise, one not.
        let a = ConvexQuad::new([(5.0, 1.0), (9.0, 5.0), (5.0, 9.0), (1.0, 5.0)]).unwrap();
        let b = ConvexQuad::new([(7.0, 1.0), (3.0, 5.0), (7.0, 9.0), (11.0, 5.0)]).unwrap();
        let mut p = canvas(12, 10);
        fill_hard_union(&mut p.image(), [Some(a), Some(b)], [210, 20, 30], 128);
        let inside = |(cx, cy): (f32, f32), x: f32, y: f32| (x - cx).abs() + (y - cy).abs() <= 4.0;
        let mut lit = 0;
        for y in 0..10 {
            for x in 0..12 {
                let (xc, yc) = (x as f32 + 0.5, y as f32 + 0.5);
                let expected = if inside((5.0, 5.0), xc, yc) || inside((7.0, 5.0), xc, yc) { 110 } else { 10 };
                assert_eq!(p.red(x, y), expected, "pixel ({x}, {y})");
                lit += (expected == 110) as usize;
            }
        }
        assert!(lit > 40, "{lit} pixels lit");
        assert!(ConvexQuad::new([(1.0, 1.0), (2.0, 2.0), (3.0, 3.0), (4.0, 4.0)]).is_none(), "no area");
    }

    #[test]
    fn hard_fills_blend_only_the_pixels_whose_centres_are_inside() {
        let rect = PlacedRect::new(Transform::identity(), (1.0, 3.0), (0.6, 1.5)).unwrap();
        let mut p = canvas(5, 3);
        fill_hard(&mut p.image(), &rect, [210, 20, 30], 128, None);
        let red: Vec<u8> = p.data.chunks_exact(3).map(|px| px[0]).collect();
        // Row 0 (centre 0.5) is outside; row 1 (centre 1.5) is on the edge: in.
        assert_eq!(red, [10, 10, 10, 10, 10, 10, 110, 110, 10, 10, 10, 10, 10, 10, 10]);
    }

    #[test]
    fn undo_puts_back_what_overlapping_hard_fills_covered() {
        let mut p = Canvas { data: (0..12 * 9 * 3).map(|i| (i * 29 % 251) as u8).collect(), width: 12 };
        let original = p.data.clone();
        let mut undo = Undo::default();
        let a = PlacedRect::new(Transform::identity(), (1.0, 7.0), (1.0, 6.0)).unwrap();
        let turned = Transform::from_row(0.8, 0.6, -0.6, 0.8, 6.0, 2.0);
        let b = PlacedRect::new(turned, (0.0, 6.0), (-1.0, 1.5)).unwrap();
        fill_hard(&mut p.image(), &a, [250, 250, 250], 200, Some(&mut undo));
        fill_hard(&mut p.image(), &b, [0, 0, 255], 120, Some(&mut undo));
        let changed = p.data.iter().zip(&original).filter(|(a, b)| a != b).count();
        assert!(changed > 60, "{changed} bytes drawn");
        undo.restore(&mut p.data);
        assert_eq!(p.data, original);
        assert!(undo.is_empty(), "forgotten once restored");
    }
}
