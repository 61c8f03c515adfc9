//! Where cars may start: the on-camera spans of the spawn lanes, and the
//! split that owns each start point.

use crate::camera::Camera;
use crate::map::{CityMap, LaneEnd, LaneId};

/// A span of a spawn lane where a car's centre is on camera.
#[derive(Debug, Clone, Copy)]
pub(super) struct SpawnSpan {
    pub(super) lane: LaneId,
    pub(super) lo: f64,
    pub(super) hi: f64,
}

/// The split that owns the start `s` metres along `lane` (to 0.1 mm, the
/// pose log's precision): train, val or test (0, 1, 2), by a hash that
/// interleaves the three finely along every lane. Every car of a split
/// starts on a point that split owns, so no car of one split starts where
/// a car of another does, and no car trajectory (starting point first) has
/// an identical twin in another split, while each split's starts still
/// cover every lane uniformly.
pub fn split_owning_start(lane: LaneId, s: f64) -> usize {
    // SplitMix64's finaliser over (lane, position in tenths of a millimetre).
    let mut z = ((lane as u64) << 40) ^ ((s * 1e4).round() as i64 as u64);
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    ((z ^ (z >> 31)) % 3) as usize
}

/// Most millimetres a drawn start moves forward to a point its split owns
/// (a pair needs both cars' points: one in nine on average).
pub(super) const OWNED_START_SEARCH_MM: usize = 200;

/// Spans of each spawn lane where a car lies wholly on camera.
pub(super) fn spawn_spans(map: &CityMap, camera: &Camera, car_length: f64) -> Vec<SpawnSpan> {
    let (lo, hi) = camera.ground_view();
    let margin = car_length;
    let step = 0.05;
    let mut spans = Vec::new();
    for lane in map.spawn_points() {
        let curve = &map.lanes[lane].curve;
        // Cars start behind the stop line, never on the crosswalk.
        let end = match map.lanes[lane].end {
            LaneEnd::Intersection { .. } => curve.length() - map.layout.stop_line_setback - 0.5,
            LaneEnd::Loop(_) => curve.length(),
        };
        let mut first = None;
        let mut last = None;
        let mut s = car_length / 2.0;
        while s <= end - car_length / 2.0 {
            let p = curve.lane_center_at(s);
            if p.x >= lo.x + margin && p.x <= hi.x - margin && p.y >= lo.y + margin && p.y <= hi.y - margin {
                first.get_or_insert(s);
                last = Some(s);
            }
            s += step;
        }
        if let (Some(a), Some(b)) = (first, last) {
            spans.push(SpawnSpan { lane, lo: a, hi: b });
        }
    }
    spans
}
