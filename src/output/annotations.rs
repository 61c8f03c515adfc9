//! `annotations.json`: NS-DR / CLEVRER-style object annotations of one
//! scenario. Frames -> objects, each object a car with its name, pixel
//! position and its instance mask as COCO run-length encoding in the
//! compressed string form (`{"size": [height, width], "counts": "..."}`), so
//! that `pycocotools.mask.decode` gives back exactly the car's mask pixels.
//!
//! Only cars with at least one pixel in a frame's mask are listed in that
//! frame. Written by `gen --annotations` (from the masks as rendered) and by
//! `export nsdr` (from the mask PNGs); both give the same bytes.

use hotcoco::mask::rle_to_string;
use hotcoco::Rle;
use serde::Serialize;

/// Format tag written into every annotations.json.
pub const ANNOTATIONS_FORMAT: &str = "causalcity-nsdr/1";
/// File name inside a scenario folder.
pub const ANNOTATIONS_FILE: &str = "annotations.json";

/// One car as the annotations name it.
#[derive(Debug, Clone)]
pub struct AnnotatedCar {
    pub id: u32,
    pub name: String,
    /// The value of the car's pixels in the mask.
    pub mask_id: u8,
}

/// A COCO RLE in its compressed string form.
#[derive(Debug, Serialize)]
pub struct CocoRle {
    /// [height, width]
    pub size: [u32; 2],
    pub counts: String,
}

#[derive(Debug, Serialize)]
struct ObjectRecord<'a> {
    id: u32,
    name: &'a str,
    mask_id: u8,
    px: f64,
    py: f64,
    area: u64,
    /// [x, y, width, height] in pixels, as COCO's bbox.
    bbox: [u32; 4],
    mask: CocoRle,
}

#[derive(Debug, Serialize)]
struct FrameRecord<'a> {
    frame_index: u32,
    frame_filename: String,
    mask_filename: String,
    objects: Vec<ObjectRecord<'a>>,
}

/// Builds a scenario's annotations one frame at a time.
pub struct AnnotationsBuilder<'a> {
    scenario: &'a str,
    width: u32,
    height: u32,
    cars: &'a [AnnotatedCar],
    /// mask value -> index into `cars`
    car_of_mask: [Option<usize>; 256],
    frames: Vec<FrameRecord<'a>>,
    /// Scratch: per mask value, the column-major start/end of its runs.
    runs: Vec<Vec<u32>>,
    /// Scratch: which columns hold any car pixel.
    occupied: Vec<u8>,
}

impl<'a> AnnotationsBuilder<'a> {
    pub fn new(scenario: &'a str, width: u32, height: u32, cars: &'a [AnnotatedCar]) -> AnnotationsBuilder<'a> {
        let mut car_of_mask = [None; 256];
        for (index, car) in cars.iter().enumerate() {
            car_of_mask[car.mask_id as usize] = Some(index);
        }
        AnnotationsBuilder {
            scenario,
            width,
            height,
            cars,
            car_of_mask,
            frames: Vec::new(),
            runs: vec![Vec::new(); 256],
            occupied: Vec::new(),
        }
    }

    /// Adds one frame: `mask` is the row-major instance mask (0 = background),
    /// `pixel_positions[i]` the logged (px, py) of `cars[i]`.
    pub fn add_frame(
        &mut self,
        frame_index: u32,
        frame_filename: String,
        mask_filename: String,
        mask: &[u8],
        pixel_positions: &[[f64; 2]],
    ) {
        let (w, h) = (self.width as usize, self.height as usize);
        debug_assert_eq!(mask.len(), w * h);
        for runs in &mut self.runs {
            runs.clear();
        }
        // One column-major pass (COCO's order) over all ids at once: each
        // id's runs as alternating start/end positions.
        let mut bbox = [[u32::MAX, u32::MAX, 0, 0]; 256];
        // Cars cover few columns: find them in a fast row-major pass and
        // walk only those column by column.
        self.occupied.clear();
        self.occupied.resize(w, 0);
        for row in mask.chunks_exact(w) {
            for (any, &v) in self.occupied.iter_mut().zip(row) {
                *any |= v;
            }
        }
        for x in (0..w).filter(|&x| self.occupied[x] != 0) {
            let mut previous = 0u8;
            for y in 0..h {
                let value = mask[y * w + x];
                if value != previous {
                    let position = (x * h + y) as u32;
                    if previous != 0 {
                        self.runs[previous as usize].push(position);
                    }
                    if value != 0 {
                        self.runs[value as usize].push(position);
                        let b = &mut bbox[value as usize];
                        b[0] = b[0].min(x as u32);
                        b[1] = b[1].min(y as u32);
                        b[2] = b[2].max(x as u32);
                    }
                    previous = value;
                }
                if value != 0 {
                    bbox[value as usize][3] = bbox[value as usize][3].max(y as u32);
                }
            }
            if previous != 0 {
                self.runs[previous as usize].push(((x + 1) * h) as u32);
            }
        }
        let total = (w * h) as u32;
        let mut objects = Vec::new();
        for (value, runs) in self.runs.iter().enumerate() {
            let Some(index) = self.car_of_mask[value].filter(|_| !runs.is_empty()) else { continue };
            let car = &self.cars[index];
            let (counts, area) = runs_to_counts(runs, total);
            let b = bbox[value];
            objects.push(ObjectRecord {
                id: car.id,
                name: &car.name,
                mask_id: car.mask_id,
                px: pixel_positions[index][0],
                py: pixel_positions[index][1],
                area,
                bbox: [b[0], b[1], b[2] - b[0] + 1, b[3] - b[1] + 1],
                mask: CocoRle {
                    size: [self.height, self.width],
                    counts: rle_to_string(&Rle { h: self.height, w: self.width, counts }),
                },
            });
        }
        objects.sort_by_key(|o| o.id);
        self.frames.push(FrameRecord { frame_index, frame_filename, mask_filename, objects });
    }

    /// The finished annotations.json.
    pub fn to_json(&self) -> Vec<u8> {
        #[derive(Serialize)]
        struct Record<'b> {
            format: &'b str,
            scenario: &'b str,
            width: u32,
            height: u32,
            frames: &'b [FrameRecord<'b>],
        }
        let record = Record {
            format: ANNOTATIONS_FORMAT,
            scenario: self.scenario,
            width: self.width,
            height: self.height,
            frames: &self.frames,
        };
        let mut json = serde_json::to_vec(&record).expect("annotations serialise");
        json.push(b'\n');
        json
    }
}

/// COCO counts (background first, alternating) from foreground run
/// boundaries [start0, end0, start1, end1, ...] in column-major positions;
/// merges runs that touch across a column boundary. Returns the counts and
/// the foreground area.
fn runs_to_counts(boundaries: &[u32], total: u32) -> (Vec<u32>, u64) {
    let mut counts = Vec::with_capacity(boundaries.len() + 1);
    let mut cursor = 0u32;
    let mut area = 0u64;
    let mut foreground_open = false;
    for pair in boundaries.chunks_exact(2) {
        let (start, end) = (pair[0], pair[1]);
        if foreground_open && start == cursor {
            // This run continues the previous one in the next column.
            *counts.last_mut().expect("an open run") += end - start;
        } else {
            counts.push(start - cursor);
            counts.push(end - start);
        }
        foreground_open = true;
        area += (end - start) as u64;
        cursor = end;
    }
    // As pycocotools: a mask that ends in foreground has no closing empty run.
    if cursor < total || counts.is_empty() {
        counts.push(total - cursor);
    }
    (counts, area)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The multi-id pass gives the same RLE as encoding each car's binary
    /// mask on its own with hotcoco (pycocotools' algorithm).
    #[test]
    fn runs_match_single_mask_encoding() {
        let (w, h) = (7usize, 5usize);
        let mut mask = vec![0u8; w * h];
        // car 1: a block touching the bottom of column 2 and top of column 3
        for &(x, y) in &[(2, 3), (2, 4), (3, 0), (3, 1), (0, 0), (6, 4)] {
            mask[y * w + x] = 1;
        }
        for &(x, y) in &[(4, 2), (5, 2), (5, 3)] {
            mask[y * w + x] = 2;
        }
        let cars = vec![
            AnnotatedCar { id: 0, name: "car00".into(), mask_id: 1 },
            AnnotatedCar { id: 1, name: "car01".into(), mask_id: 2 },
        ];
        let mut builder = AnnotationsBuilder::new("s", w as u32, h as u32, &cars);
        builder.add_frame(0, "rgb/0.png".into(), "mask/0.png".into(), &mask, &[[0.0, 0.0], [1.0, 1.0]]);
        for (object, car) in builder.frames[0].objects.iter().zip(&cars) {
            let column_major: Vec<u8> = (0..w * h).map(|i| (mask[(i % h) * w + i / h] == car.mask_id) as u8).collect();
            let expected = hotcoco::mask::encode(&column_major, h as u32, w as u32).unwrap();
            assert_eq!(object.mask.counts, rle_to_string(&expected), "car {}", car.name);
            assert_eq!(object.area, column_major.iter().map(|&v| v as u64).sum::<u64>());
        }
        assert_eq!(builder.frames[0].objects[1].bbox, [4, 2, 2, 2]);
    }
}
