//! Tests of the vocabulary: text import, binary format, training, transform and scoring.

use super::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A hand-written 2×2 vocabulary: node 1 (zeros) with leaves 3 (zeros) and 4 (low nibbles set),
/// node 2 (ones) with leaves 5 (ones) and 6 (high nibbles cleared).
fn tiny_text() -> String {
    let row = |parent: u32, leaf: u8, byte: u8, w: f32| {
        let bytes: Vec<String> = (0..32).map(|_| byte.to_string()).collect();
        format!("{parent} {leaf} {} {w}\n", bytes.join(" "))
    };
    let mut s = String::from("2 2 0 0\n");
    s += &row(0, 0, 0, 0.0);
    s += &row(0, 0, 255, 0.0);
    s += &row(1, 1, 0, 0.5);
    s += &row(1, 1, 15, 1.5);
    s += &row(2, 1, 255, 2.0);
    s += &row(2, 1, 15, 0.0);
    s += "\n"; // trailing empty line, as in the shipped ORBvoc.txt
    s
}

fn tiny() -> Vocabulary {
    match Vocabulary::from_orbvoc_text(std::io::Cursor::new(tiny_text())) {
        Ok(v) => v,
        Err(e) => panic!("tiny vocabulary failed to load: {e}"),
    }
}

#[test]
fn import_tiny_orbvoc_text() {
    let v = tiny();
    assert_eq!((v.branching(), v.levels()), (2, 2));
    assert_eq!(v.node_count(), 7);
    assert_eq!(v.word_count(), 4);
    // Word ids count leaves in node order: nodes 3, 4, 5, 6 → words 0..4.
    assert_eq!(v.word_of(&[0; 32]), (0, 0.5));
    assert_eq!(v.word_of(&[0x0E; 32]).0, 1);
    assert_eq!(v.word_of(&[0xFF; 32]), (2, 2.0));
    assert_eq!(v.word_of(&[0x1F; 32]).0, 3);
    assert_eq!(v.word_weight(1), 1.5);
    assert_eq!(v.parent(5), Some(2));
    assert_eq!(v.node_depth(6), Some(2));
}

#[test]
fn transform_weights_groups_and_skips_zero_weight_words() {
    let v = tiny();
    let descs = [[0u8; 32], [0x0F; 32], [0xFF; 32], [0x1F; 32], [0x01; 32]];
    let (bow, fv) = v.transform(&descs);
    // Features 0 and 4 → word 0 (0.5 each), 1 → word 1 (1.5), 2 → word 2 (2.0); word 3 has
    // zero weight and is dropped from both vectors.
    let total = 0.5 + 0.5 + 1.5 + 2.0;
    assert_eq!(bow.len(), 3);
    assert!((bow.get(0).unwrap_or(0.0) - 1.0 / total).abs() < 1e-12);
    assert!((bow.get(1).unwrap_or(0.0) - 1.5 / total).abs() < 1e-12);
    assert!((bow.get(2).unwrap_or(0.0) - 2.0 / total).abs() < 1e-12);
    assert_eq!(bow.get(3), None);
    let s: f64 = bow.iter().map(|p| p.1).sum();
    assert!((s - 1.0).abs() < 1e-12);
    // L = 2 with levels_up = 4 clamps to depth 1: groups under nodes 1 and 2.
    assert_eq!(fv.as_slice(), &[(1, vec![0, 1, 4]), (2, vec![2])]);
    assert_eq!(fv.get(1), Some(&[0usize, 1, 4][..]));
}

#[test]
fn l1_score_properties() {
    let a = BowVector::from_weights(vec![(1, 2.0), (3, 1.0), (1, 1.0)]);
    assert_eq!(a.as_slice(), &[(1, 0.75), (3, 0.25)]);
    let b = BowVector::from_weights(vec![(3, 1.0), (7, 1.0)]);
    let c = BowVector::from_weights(vec![(9, 1.0)]);
    assert!((a.l1_score(&a) - 1.0).abs() < 1e-12);
    assert_eq!(a.l1_score(&c), 0.0);
    // 1 − ½(|0.75−0| + |0.25−0.5| + |0−0.5|) = 1 − ½·1.5 = 0.25
    assert!((a.l1_score(&b) - 0.25).abs() < 1e-12);
    assert!((a.l1_score(&b) - b.l1_score(&a)).abs() < 1e-12);
    assert_eq!(a.l1_score(&BowVector::default()), 0.0);
}

#[test]
fn corrupt_text_gives_errors() {
    let good = tiny_text();
    let cases: Vec<String> = vec![
        String::new(),
        "10 6 0\n".into(),
        "10 6 x 0\n".into(),
        "10 6 1 0\n".into(),                    // unsupported scoring
        "10 6 0 0\n".into(),                    // no nodes
        good.replace("2 1 15 15", "7 1 15 15"), // forward parent
        good.replacen(" 255 ", " 256 ", 1),
        good.replacen("0.5", "abc", 1),
        good.replacen("1 1 0 0", "1 2 0 0", 1), // bad leaf flag
        good.replacen("0 0 255", "0 1 255", 1), // leaf flag on a node with children
        good.replacen(" 0.5\n", "\n", 1),       // missing field
    ];
    for (i, c) in cases.iter().enumerate() {
        let r = Vocabulary::from_orbvoc_text(std::io::Cursor::new(c.clone()));
        assert!(r.is_err(), "case {i} should fail: {c:?}");
    }
}

fn random_images(n_img: usize, per: usize, seed: u64) -> Vec<Vec<Descriptor>> {
    // Descriptors around a few prototypes, so that the clustering has structure.
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let protos: Vec<Descriptor> = (0..40).map(|_| rng.random()).collect();
    (0..n_img)
        .map(|_| {
            (0..per)
                .map(|_| {
                    let mut d = protos[rng.random_range(0..protos.len())];
                    for _ in 0..10 {
                        let b = rng.random_range(0..256);
                        d[b / 8] ^= 1 << (b % 8);
                    }
                    d
                })
                .collect()
        })
        .collect()
}

#[test]
fn training_is_deterministic_and_round_trips() {
    let imgs = random_images(20, 300, 3);
    let p = TrainParams {
        k: 5,
        levels: 3,
        ..TrainParams::default()
    };
    let a = Vocabulary::train(&imgs, &p).unwrap_or_else(|e| panic!("{e}"));
    let b = Vocabulary::train(&imgs, &p).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(a, b);
    // 6000 descriptors take the parallel path; the thread count must not matter.
    for threads in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap_or_else(|e| panic!("{e}"));
        let c = pool
            .install(|| Vocabulary::train(&imgs, &p))
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(a, c, "{threads} threads");
    }
    assert!(
        a.word_count() > 25 && a.word_count() <= 125,
        "{}",
        a.word_count()
    );
    for n in 1..a.node_count() as u32 {
        assert!(a.node_depth(n).unwrap_or(99) <= 3);
    }
    let bytes = a.to_bytes();
    let c = Vocabulary::from_bytes(&bytes).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(a, c);
    // A different seed gives a different tree.
    let d = Vocabulary::train(
        &imgs,
        &TrainParams {
            seed: 9,
            ..p.clone()
        },
    )
    .unwrap_or_else(|e| panic!("{e}"));
    assert_ne!(a.to_bytes(), d.to_bytes());
    // An image scores higher against itself than against an unrelated one.
    let (va, _) = a.transform(&imgs[0]);
    let (vb, _) = a.transform(&imgs[1]);
    let noise: Vec<Descriptor> = {
        let mut rng = ChaCha8Rng::seed_from_u64(77);
        (0..300).map(|_| rng.random()).collect()
    };
    let (vn, _) = a.transform(&noise);
    assert!((va.iter().map(|p| p.1).sum::<f64>() - 1.0).abs() < 1e-9);
    assert!(a.score(&va, &vb) > a.score(&va, &vn));
}

#[test]
fn training_rejects_bad_input() {
    assert!(Vocabulary::train(&[], &TrainParams::default()).is_err());
    assert!(Vocabulary::train(&[vec![[0; 32]]], &TrainParams::default()).is_err());
    let imgs = random_images(2, 50, 1);
    let bad = TrainParams {
        k: 1,
        ..TrainParams::default()
    };
    assert!(Vocabulary::train(&imgs, &bad).is_err());
    // Identical descriptors do not break training.
    let same = vec![vec![[7u8; 32]; 100]; 3];
    let v = Vocabulary::train(&same, &TrainParams::default()).unwrap_or_else(|e| panic!("{e}"));
    assert!(v.word_count() >= 1);
}

#[test]
fn corrupt_binary_gives_errors() {
    let v = tiny();
    let bytes = v.to_bytes();
    assert_eq!(Vocabulary::from_bytes(&bytes).ok(), Some(v));
    assert!(matches!(
        Vocabulary::from_bytes(b"nope"),
        Err(VocabError::BadMagic)
    ));
    assert!(Vocabulary::from_bytes(&bytes[..bytes.len() - 1]).is_err());
    assert!(Vocabulary::from_bytes(&bytes[..20]).is_err());
    let mut flipped = bytes.clone();
    flipped[50] ^= 1;
    assert!(matches!(
        Vocabulary::from_bytes(&flipped),
        Err(VocabError::Checksum)
    ));
    let mut version = bytes.clone();
    version[8] = 9;
    assert!(matches!(
        Vocabulary::from_bytes(&version),
        Err(VocabError::UnsupportedVersion { got: 9, .. })
    ));
    let mut count = bytes.clone();
    count[28..32].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(Vocabulary::from_bytes(&count).is_err());
    // Arbitrary garbage after a valid magic never panics.
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    for len in [8usize, 40, 100, 1000] {
        let mut g: Vec<u8> = (0..len).map(|_| rng.random()).collect();
        g[..8].copy_from_slice(b"DPXVOCAB");
        assert!(Vocabulary::from_bytes(&g).is_err());
    }
}

#[test]
fn save_and_load_files() {
    let dir = match tempfile::tempdir() {
        Ok(d) => d,
        Err(e) => panic!("{e}"),
    };
    let v = tiny();
    let bin = dir.path().join("v.dpxvoc");
    v.save(&bin).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(Vocabulary::load(&bin).ok(), Some(v.clone()));
    let txt = dir.path().join("ORBvoc.txt");
    std::fs::write(&txt, tiny_text()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(Vocabulary::load(&txt).ok(), Some(v));
    assert!(matches!(
        Vocabulary::load(&dir.path().join("missing")),
        Err(VocabError::Io { .. })
    ));
    let gz = dir.path().join("ORBvoc.txt.tar.gz");
    std::fs::write(&gz, [0x1f, 0x8b, 8, 0, 0, 0]).unwrap_or_else(|e| panic!("{e}"));
    match Vocabulary::load(&gz) {
        Err(VocabError::Unsupported(m)) => assert!(m.contains("extract"), "{m}"),
        other => panic!("expected a gzip hint, got {other:?}"),
    }
}

#[test]
fn embedded_default_loads_and_ranks_neighbours_higher() {
    let t = std::time::Instant::now();
    let v = Vocabulary::embedded_default().unwrap_or_else(|e| panic!("{e}"));
    eprintln!(
        "embedded default: {} nodes, {} words, parsed in {:?}",
        v.node_count(),
        v.word_count(),
        t.elapsed()
    );
    assert_eq!((v.branching(), v.levels()), (10, 4));
    assert!(v.word_count() > 5000);
    let Some(f0) = crate::orb::tests::fr1_xyz_frame(100) else {
        return;
    };
    let Some(f1) = crate::orb::tests::fr1_xyz_frame(101) else {
        return;
    };
    let Some(far) = crate::orb::tests::fr1_xyz_frame(290) else {
        return;
    };
    let orb = crate::orb::OrbExtractor::default();
    let (_, d0) = orb.extract(&f0);
    let (_, d1) = orb.extract(&f1);
    let (_, d2) = orb.extract(&far);
    let (b0, fv0) = v.transform(&d0);
    let (b1, _) = v.transform(&d1);
    let (b2, _) = v.transform(&d2);
    let sum: f64 = b0.iter().map(|p| p.1).sum();
    assert!((sum - 1.0).abs() < 1e-9, "{sum}");
    assert!(b0.iter().all(|p| p.1 > 0.0));
    // Every kept feature is in exactly one group, groups are depth-1 nodes here (L − 4 → 1).
    let grouped: usize = fv0.iter().map(|g| g.1.len()).sum();
    assert!(grouped > d0.len() / 2 && grouped <= d0.len());
    assert!(fv0.iter().all(|g| v.node_depth(g.0) == Some(1)));
    let (near, distant) = (v.score(&b0, &b1), v.score(&b0, &b2));
    eprintln!("score neighbour {near:.4}, distant {distant:.4}");
    assert!(near > distant, "neighbour {near} vs distant {distant}");
}

#[test]
fn feature_vector_depth_follows_levels_up() {
    let imgs = random_images(10, 400, 11);
    let p = TrainParams {
        k: 5,
        levels: 3,
        ..TrainParams::default()
    };
    let v = Vocabulary::train(&imgs, &p).unwrap_or_else(|e| panic!("{e}"));
    let descs = &imgs[0];
    for (levels_up, depth) in [(0usize, 3usize), (1, 2), (2, 1), (4, 1)] {
        assert_eq!(v.group_depth(levels_up), depth);
        let (bow, fv) = v.transform_with_levels_up(descs, levels_up);
        let mut seen: Vec<usize> = fv.iter().flat_map(|g| g.1.iter().copied()).collect();
        let n = seen.len();
        seen.sort_unstable();
        seen.dedup();
        assert_eq!(seen.len(), n, "a feature in two groups");
        assert!(fv.as_slice().windows(2).all(|w| w[0].0 < w[1].0));
        for (node, feats) in fv.iter() {
            // Groups sit at the requested depth, or are leaves above it.
            let d = v.node_depth(*node).unwrap_or(99);
            assert!(d == depth || (d < depth && v.children(*node as usize).is_empty()));
            // Each grouped feature's word lies under the group node.
            for &f in feats {
                let (word, _) = v.word_of(&descs[f]);
                let mut up = v.node_of_word[word as usize];
                while v.node_depth(up).unwrap_or(0) > d {
                    up = v.parent(up).unwrap_or(0);
                }
                assert_eq!(up, *node);
                assert!(bow.get(word).is_some());
            }
        }
    }
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(200))]

    /// Random edits of a valid text vocabulary give a vocabulary or an error, never a panic.
    #[test]
    fn text_parser_never_panics(pos in 0usize..4000, byte in 0u8..128, cut in 0usize..4000) {
        let mut t = tiny_text().into_bytes();
        let p = pos % t.len();
        t[p] = byte;
        t.truncate(cut.max(1).min(t.len()));
        let _ = Vocabulary::from_orbvoc_text(std::io::Cursor::new(t));
    }

    /// Random binary input behind a valid header never panics.
    #[test]
    fn binary_parser_never_panics(data in proptest::collection::vec(0u8..=255, 0..300), n in 0u32..20) {
        let mut b = tiny().to_bytes();
        b.truncate(32);
        b[28..32].copy_from_slice(&n.to_le_bytes());
        b.extend_from_slice(&data);
        let _ = Vocabulary::from_bytes(&b);
    }
}
