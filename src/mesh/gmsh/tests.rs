use super::*;

#[test]
fn integer_tokens() {
    assert_eq!(parse_u64_digits(b"0"), Some(0));
    assert_eq!(parse_u64_digits(b"+17"), Some(17));
    assert_eq!(parse_u64_digits(b"18446744073709551615"), Some(u64::MAX));
    assert_eq!(parse_u64_digits(b"18446744073709551616"), None);
    for bad in [&b""[..], b"+", b"-1", b"1.0", b"1e3", b"12a"] {
        assert_eq!(parse_u64_digits(bad), None);
    }
    assert_eq!(parse_i64_digits(b"-9223372036854775808"), Some(i64::MIN));
    assert_eq!(parse_i64_digits(b"-9223372036854775809"), None);
    assert_eq!(parse_i64_digits(b"9223372036854775808"), None);
    assert_eq!(parse_i64_digits(b"-3"), Some(-3));
}

#[test]
fn tag_maps_dense_sparse_and_duplicates() {
    let dense = TagMap::build(&[3, 1, 2]).unwrap();
    assert!(matches!(dense, TagMap::Dense(_)));
    assert_eq!(
        [1, 2, 3, 0, 4].map(|t| dense.get(t)),
        [Some(1), Some(2), Some(0), None, None]
    );
    let sparse = TagMap::build(&[u64::MAX, 5]).unwrap();
    assert!(matches!(sparse, TagMap::Sparse(_)));
    assert_eq!(
        [u64::MAX, 5, 6].map(|t| sparse.get(t)),
        [Some(0), Some(1), None]
    );
    assert_eq!(TagMap::build(&[4, 5, 4]).err(), Some(2));
    assert_eq!(TagMap::build(&[1 << 40, 5, 1 << 40]).err(), Some(2));
}

#[test]
fn ignored_summary_line() {
    let mut ignored = BTreeMap::new();
    assert_eq!(ignored_summary(&ignored), None);
    ignored.insert(2, 1200);
    ignored.insert(15, 34);
    assert_eq!(
        ignored_summary(&ignored).unwrap(),
        "ignored 1234 elements of other types (2: 1200 triangles, 15: 34 points)"
    );
}

/// The walk through a gmsh-written binary $Entities lands exactly on
/// $EndEntities (so the search fallback is not what makes it work).
#[test]
fn walks_gmsh_binary_entities() {
    for name in ["cube_tet4_msh41_bin.msh", "sphere_tet10_msh41_bin.msh"] {
        let data = std::fs::read(super::super::tests::fixture(name)).unwrap();
        let start = data.windows(10).position(|w| w == b"$Entities\n").unwrap() + 10;
        let mut p = Parser {
            data: &data,
            pos: start,
            path: Path::new(name),
            binary: true,
            big_endian: false,
        };
        walk_entities_binary(&mut p).unwrap();
        p.section_end("Entities").unwrap();
    }
}
