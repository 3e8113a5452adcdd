//! Tracks: pairwise matches joined into multi-view observations (union–find over every
//! keypoint of every view). Matches are joined best first (smallest descriptor distance,
//! then pair and keypoint order); a match that would put two keypoints of one view into one
//! track contradicts what is already joined and is refused, as COLMAP's track builder does —
//! a few wrong matches then cost a few observations, not whole chains of tracks.

use super::matching::Match;

/// One observation: view index and keypoint index in that view.
pub type Obs = (u32, u32);

/// Tracks joined from the matches.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Tracks {
    /// Observations per track, by view; tracks ordered by their first keypoint.
    pub tracks: Vec<Vec<Obs>>,
    /// Matches refused because they would put two keypoints of one view into one track.
    pub conflicting_matches: usize,
}

fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        let p = parent[x as usize];
        parent[x as usize] = parent[p as usize];
        x = p;
    }
    x
}

/// Whether two sorted lists share an element.
fn intersect(a: &[u32], b: &[u32]) -> bool {
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        match a[i].cmp(&b[j]) {
            std::cmp::Ordering::Less => i += 1,
            std::cmp::Ordering::Greater => j += 1,
            std::cmp::Ordering::Equal => return true,
        }
    }
    false
}

/// Joins `matches` (per view pair) into tracks. `counts[v]` is the number of keypoints of view
/// `v`. The result does not depend on the order of the pairs in `matches`.
pub fn join(counts: &[usize], matches: &[((usize, usize), Vec<Match>)]) -> Tracks {
    let mut offsets = Vec::with_capacity(counts.len() + 1);
    offsets.push(0usize);
    for c in counts {
        offsets.push(offsets.last().copied().unwrap_or(0) + c);
    }
    let total = *offsets.last().unwrap_or(&0);
    // Every match as (distance, a, b, i, j), best first.
    let mut order: Vec<(u32, u32, u32, u32, u32)> = matches
        .iter()
        .flat_map(|((a, b), ms)| {
            ms.iter()
                .map(move |&(i, j, d)| (d, *a as u32, *b as u32, i, j))
        })
        .collect();
    order.sort_unstable();
    order.dedup();
    let mut parent: Vec<u32> = (0..total as u32).collect();
    // The views of each root's track, sorted (a root alone holds its own view).
    let mut views: Vec<Vec<u32>> = Vec::new();
    let mut view_of = Vec::with_capacity(total);
    for (v, c) in counts.iter().enumerate() {
        view_of.extend(std::iter::repeat_n(v as u32, *c));
    }
    let mut slot: Vec<u32> = vec![u32::MAX; total];
    let mut tracks = Tracks::default();
    for &(_, a, b, i, j) in &order {
        let x = find(&mut parent, (offsets[a as usize] + i as usize) as u32);
        let y = find(&mut parent, (offsets[b as usize] + j as usize) as u32);
        if x == y {
            continue;
        }
        for r in [x, y] {
            if slot[r as usize] == u32::MAX {
                slot[r as usize] = views.len() as u32;
                views.push(vec![view_of[r as usize]]);
            }
        }
        let (vx, vy) = (slot[x as usize] as usize, slot[y as usize] as usize);
        if intersect(&views[vx], &views[vy]) {
            tracks.conflicting_matches += 1;
            continue;
        }
        // The smaller index becomes the root.
        let (root, child, keep, drop) = if x < y {
            (x, y, vx, vy)
        } else {
            (y, x, vy, vx)
        };
        parent[child as usize] = root;
        let moved = std::mem::take(&mut views[drop]);
        let merged = &mut views[keep];
        merged.extend(moved);
        merged.sort_unstable();
        slot[root as usize] = keep as u32;
    }
    // Group by root, in order of each track's first keypoint (roots are the smallest member).
    let mut group_of = vec![u32::MAX; total];
    let mut groups: Vec<Vec<Obs>> = Vec::new();
    for view in 0..counts.len() {
        for k in 0..counts[view] {
            let g = offsets[view] + k;
            let r = find(&mut parent, g as u32) as usize;
            if r == g {
                group_of[r] = groups.len() as u32;
                groups.push(Vec::new());
            }
            groups[group_of[r] as usize].push((view as u32, k as u32));
        }
    }
    tracks.tracks = groups.into_iter().filter(|g| g.len() >= 2).collect();
    tracks
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_chain_into_tracks_and_contradictions_are_refused() {
        // Views of 3, 2, 2 keypoints. 0:0–1:1–2:0 is one track; 0:2–1:0 another.
        let counts = [3, 2, 2];
        let m = vec![
            ((0, 1), vec![(0, 1, 10)]),
            ((1, 2), vec![(1, 0, 12)]),
            ((0, 1), vec![(2, 0, 5)]),
        ];
        let t = join(&counts, &m);
        assert_eq!(
            t.tracks,
            vec![vec![(0, 0), (1, 1), (2, 0)], vec![(0, 2), (1, 0)]]
        );
        assert_eq!(t.conflicting_matches, 0);
        // 1:0–2:1 (distance 20) joins view 2 to the second track; 0:1–2:1 (distance 30) would
        // then put 0:1 beside 0:2: refused, 0:1 stays alone.
        let mut m2 = m.clone();
        m2.push(((0, 2), vec![(1, 1, 30)]));
        m2.push(((1, 2), vec![(0, 1, 20)]));
        let t2 = join(&counts, &m2);
        assert_eq!(
            t2.tracks,
            vec![vec![(0, 0), (1, 1), (2, 0)], vec![(0, 2), (1, 0), (2, 1)]]
        );
        assert_eq!(t2.conflicting_matches, 1);
        // Order of the pairs does not matter.
        let mut m3 = m2.clone();
        m3.reverse();
        assert_eq!(join(&counts, &m3), t2);
    }
}
