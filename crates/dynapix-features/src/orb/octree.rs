//! Quadtree keypoint distribution of ORB-SLAM2 (`ORBextractor::DistributeOctTree`, spec §6.2):
//! start from ≈ width/height vertical strips, split nodes into quadrants until there are at least
//! N nodes or nothing changes, then keep the strongest keypoint of every node. This spreads
//! features evenly instead of clustering them on the most textured region.
//!
//! The node list order of the reference (children pushed to the front of a `std::list`) is
//! reproduced, so ties are broken as upstream. The one deviation: in the final refinement
//! phase upstream sorts `(size, node pointer)` pairs, i.e. ties by heap address; here ties fall
//! back to creation order, which is deterministic.

/// A candidate keypoint in coordinates relative to the distribution area.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Cand {
    pub x: f32,
    pub y: f32,
    pub response: f32,
}

#[derive(Clone, Debug)]
struct Node {
    ul: (i32, i32),
    ur: (i32, i32),
    bl: (i32, i32),
    br: (i32, i32),
    keys: Vec<u32>,
    no_more: bool,
    /// Creation serial, the deterministic replacement of upstream's pointer tie-break.
    serial: u64,
}

impl Node {
    fn divide(&self, cands: &[Cand], serial: &mut u64) -> [Node; 4] {
        let half_x = ((self.ur.0 - self.ul.0) as f32 / 2.0).ceil() as i32;
        let half_y = ((self.br.1 - self.ul.1) as f32 / 2.0).ceil() as i32;
        let mk = |ul, ur, bl, br, serial: &mut u64| {
            *serial += 1;
            Node {
                ul,
                ur,
                bl,
                br,
                keys: Vec::new(),
                no_more: false,
                serial: *serial,
            }
        };
        let n1ur = (self.ul.0 + half_x, self.ul.1);
        let n1bl = (self.ul.0, self.ul.1 + half_y);
        let n1br = (self.ul.0 + half_x, self.ul.1 + half_y);
        let mut n1 = mk(self.ul, n1ur, n1bl, n1br, serial);
        let mut n2 = mk(n1ur, self.ur, n1br, (self.ur.0, self.ul.1 + half_y), serial);
        let mut n3 = mk(n1bl, n1br, self.bl, (n1br.0, self.bl.1), serial);
        let mut n4 = mk(n1br, n2.br, n3.br, self.br, serial);
        for &k in &self.keys {
            let c = &cands[k as usize];
            let left = c.x < n1ur.0 as f32;
            let top = c.y < n1br.1 as f32;
            match (left, top) {
                (true, true) => n1.keys.push(k),
                (true, false) => n3.keys.push(k),
                (false, true) => n2.keys.push(k),
                (false, false) => n4.keys.push(k),
            }
        }
        for n in [&mut n1, &mut n2, &mut n3, &mut n4] {
            n.no_more = n.keys.len() == 1;
        }
        [n1, n2, n3, n4]
    }
}

/// Distributes `cands` (relative to the area `[0, max_x − min_x) × [0, max_y − min_y)`) and
/// returns the indices of the kept candidates, in upstream's output order.
pub(crate) fn distribute(
    cands: &[Cand],
    min_x: i32,
    max_x: i32,
    min_y: i32,
    max_y: i32,
    n: usize,
) -> Vec<usize> {
    if cands.is_empty() || max_x <= min_x || max_y <= min_y {
        return Vec::new();
    }
    let (wd, ht) = ((max_x - min_x) as f32, (max_y - min_y) as f32);
    // Upstream divides by zero when the area is more than twice as tall as wide; use ≥ 1 strip.
    let n_ini = ((wd / ht).round() as usize).max(1);
    let hx = wd / n_ini as f32;
    let mut serial = 0u64;
    let mut ini: Vec<Node> = (0..n_ini)
        .map(|i| {
            serial += 1;
            let x0 = (hx * i as f32) as i32;
            let x1 = (hx * (i + 1) as f32) as i32;
            Node {
                ul: (x0, 0),
                ur: (x1, 0),
                bl: (x0, max_y - min_y),
                br: (x1, max_y - min_y),
                keys: Vec::new(),
                no_more: false,
                serial,
            }
        })
        .collect();
    for (k, c) in cands.iter().enumerate() {
        let i = ((c.x / hx).max(0.0) as usize).min(n_ini - 1);
        ini[i].keys.push(k as u32);
    }
    // `nodes` is the list, front first.
    let mut nodes: Vec<Node> = ini
        .into_iter()
        .filter(|nd| !nd.keys.is_empty())
        .map(|mut nd| {
            nd.no_more = nd.keys.len() == 1;
            nd
        })
        .collect();

    loop {
        let prev_size = nodes.len();
        // One pass: every node with > 1 keys is replaced by its non-empty children, which
        // upstream pushes to the list front (so they come out in reverse creation order).
        let mut front: Vec<Node> = Vec::new();
        let mut kept: Vec<Node> = Vec::with_capacity(nodes.len());
        let mut to_expand = 0usize;
        for nd in nodes.drain(..) {
            if nd.no_more {
                kept.push(nd);
                continue;
            }
            for child in nd.divide(cands, &mut serial) {
                if !child.keys.is_empty() {
                    if child.keys.len() > 1 {
                        to_expand += 1;
                    }
                    front.push(child);
                }
            }
        }
        front.reverse();
        front.extend(kept);
        nodes = front;

        if nodes.len() >= n || nodes.len() == prev_size {
            break;
        }
        if nodes.len() + to_expand * 3 > n {
            refine(&mut nodes, cands, n, &mut serial);
            break;
        }
    }

    nodes
        .iter()
        .map(|nd| {
            let mut best = nd.keys[0] as usize;
            for &k in &nd.keys[1..] {
                if cands[k as usize].response > cands[best].response {
                    best = k as usize;
                }
            }
            best
        })
        .collect()
}

/// Final phase: split the most populated expandable nodes first, one at a time, until the
/// node count reaches `n` or stops changing.
fn refine(nodes: &mut Vec<Node>, cands: &[Cand], n: usize, serial: &mut u64) {
    loop {
        let prev_size = nodes.len();
        // Expandable nodes (> 1 key) ordered by size, largest first; ties by newest first,
        // mirroring the reverse iteration over an ascending sort.
        let mut order: Vec<(usize, u64)> = nodes
            .iter()
            .filter(|nd| nd.keys.len() > 1)
            .map(|nd| (nd.keys.len(), nd.serial))
            .collect();
        if order.is_empty() {
            return;
        }
        order.sort_unstable();
        let mut done = false;
        for &(_, ser) in order.iter().rev() {
            let Some(pos) = nodes.iter().position(|nd| nd.serial == ser) else {
                continue;
            };
            let nd = nodes.remove(pos);
            let children = nd.divide(cands, serial);
            for child in children {
                if !child.keys.is_empty() {
                    nodes.insert(0, child);
                }
            }
            if nodes.len() >= n {
                done = true;
                break;
            }
        }
        if done || nodes.len() >= n || nodes.len() == prev_size {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_strongest_per_node_and_caps_count() {
        // A dense strong cluster plus weak points spread over the area: the distribution must
        // keep spread points instead of only the strong cluster.
        let mut c = Vec::new();
        for i in 0..100 {
            c.push(Cand {
                x: 10.0 + (i % 10) as f32,
                y: 10.0 + (i / 10) as f32,
                response: 100.0 + i as f32,
            });
        }
        for i in 0..400u32 {
            // Deterministic scatter (multiplicative hashing).
            let h = i.wrapping_mul(2_654_435_761);
            c.push(Cand {
                x: (h % 397) as f32,
                y: ((h / 397) % 297) as f32,
                response: 10.0,
            });
        }
        let kept = distribute(&c, 0, 400, 0, 300, 40);
        assert!(kept.len() >= 40 && kept.len() <= 43, "{}", kept.len());
        let in_cluster = kept
            .iter()
            .filter(|&&k| c[k].x < 20.0 && c[k].y < 20.0)
            .count();
        assert!(in_cluster <= 2, "{in_cluster}");
        let mut u = kept.clone();
        u.sort();
        u.dedup();
        assert_eq!(u.len(), kept.len());
        // Within the cluster node the strongest point wins.
        let kept1 = distribute(&c[..100], 0, 400, 0, 300, 1);
        assert_eq!(kept1, vec![99]);
    }

    #[test]
    fn empty_and_single() {
        assert!(distribute(&[], 0, 10, 0, 10, 5).is_empty());
        let c = [Cand {
            x: 1.0,
            y: 1.0,
            response: 1.0,
        }];
        assert_eq!(distribute(&c, 0, 10, 0, 10, 5), vec![0]);
    }
}
