//! Write→read round trips of every image format on oblique anisotropic grids: exact data and
//! affines to 1e-9 mm (NIfTI stores the affine in f32: exact for the dyadic grid, 1e-5 mm else).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test helpers

mod image_common;

use std::collections::BTreeMap;

use image_common::{all_types, assert_same, general_grid, oblique_grid};
use resecta_geom::grid::LabelMap;
use resecta_geom::{Vec3, Volume, VoxelLimit};
use resecta_io::nifti::{nifti_bytes, read_nifti_bytes};
use resecta_io::nrrd::{
    Segmentation, read_nrrd_bytes, read_seg_nrrd, read_seg_nrrd_bytes, seg_nrrd_bytes,
    write_seg_nrrd,
};
use resecta_io::{ErrorKind, Image, VoxelData, read_image, write_image};

const LIMIT: VoxelLimit = VoxelLimit(1 << 30);

fn round_trip_files(ext: &str, grid_tol: f64, general: bool) {
    let dir = tempfile::tempdir().unwrap();
    let grid = if general {
        general_grid()
    } else {
        oblique_grid()
    };
    for (k, img) in all_types(&grid).iter().enumerate() {
        let path = dir.path().join(format!("img{k}.{ext}"));
        write_image(&path, img).unwrap();
        let back = read_image(&path, LIMIT).unwrap();
        assert_same(img, &back, grid_tol);
    }
}

#[test]
fn nifti_nii_and_nii_gz_round_trip_exactly_on_dyadic_oblique_grid() {
    round_trip_files("nii", 1e-9, false);
    round_trip_files("nii.gz", 1e-9, false);
}

#[test]
fn nifti_general_oblique_grid_round_trips_to_f32_precision() {
    round_trip_files("nii.gz", 1e-5, true);
}

#[test]
fn nrrd_attached_and_detached_round_trip_exactly() {
    round_trip_files("nrrd", 1e-9, true);
    round_trip_files("nrrd", 1e-9, false);
    round_trip_files("nhdr", 1e-9, true);
}

#[test]
fn nhdr_writes_a_relative_detached_gzip_data_file() {
    let dir = tempfile::tempdir().unwrap();
    let img = &all_types(&general_grid())[3];
    let path = dir.path().join("vol.nhdr");
    write_image(&path, img).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(text.contains("data file: vol.raw.gz\n"), "{text}");
    assert!(dir.path().join("vol.raw.gz").is_file());
}

#[test]
fn metaimage_mha_and_mhd_raw_and_compressed_round_trip_exactly() {
    let dir = tempfile::tempdir().unwrap();
    for grid in [general_grid(), oblique_grid()] {
        for (k, img) in all_types(&grid).iter().enumerate() {
            for ext in ["mha", "mhd"] {
                for compress in [false, true] {
                    let path = dir.path().join(format!("m{k}{compress}.{ext}"));
                    resecta_io::metaimage::write_metaimage(&path, img, compress).unwrap();
                    assert_same(img, &read_image(&path, LIMIT).unwrap(), 1e-9);
                }
            }
        }
    }
    // .mhd data files sit beside the header with the ITK names.
    assert!(dir.path().join("m0true.zraw").is_file());
    assert!(dir.path().join("m0false.raw").is_file());
}

#[test]
fn same_volume_in_every_format_has_the_same_world_coordinates() {
    let dir = tempfile::tempdir().unwrap();
    let img = &all_types(&oblique_grid())[6];
    let reads: Vec<Image> = ["a.nii.gz", "a.nrrd", "a.nhdr", "a.mha", "a.mhd"]
        .iter()
        .map(|name| {
            let p = dir.path().join(name);
            write_image(&p, img).unwrap();
            read_image(&p, LIMIT).unwrap()
        })
        .collect();
    for ijk in [[0, 0, 0], [6, 4, 3], [3, 1, 2]] {
        let want = img.grid().voxel_center(ijk);
        for r in &reads {
            let got = r.grid().voxel_center(ijk);
            assert!((got - want).norm() < 1e-9, "{got} vs {want}");
            let o = r.grid().offset(ijk);
            assert_eq!(r.data().get_f64(o), img.data().get_f64(o));
        }
    }
}

/// Converts a little-endian NIfTI-1 file to big-endian, field by field.
fn to_big_endian(le: &[u8], value_size: usize) -> Vec<u8> {
    let mut b = le.to_vec();
    let mut swap = |off: usize, size: usize| b[off..off + size].reverse();
    let fields: &[(usize, usize, usize)] = &[
        // (offset, size, count)
        (0, 4, 1),
        (32, 4, 1),
        (36, 2, 1),
        (40, 2, 8),
        (56, 4, 3),
        (68, 2, 4),
        (76, 4, 11),
        (120, 2, 1),
        (124, 4, 4),
        (140, 4, 2),
        (252, 2, 2),
        (256, 4, 18),
    ];
    for &(off, size, count) in fields {
        for k in 0..count {
            swap(off + k * size, size);
        }
    }
    for off in (352..le.len()).step_by(value_size) {
        swap(off, value_size);
    }
    b
}

#[test]
fn nifti_big_endian_input_reads_like_little_endian() {
    for img in all_types(&general_grid()) {
        let le = nifti_bytes(&img, false).unwrap();
        let be = to_big_endian(&le, img.data().scalar_type().size());
        assert_ne!(le, be);
        let a = read_nifti_bytes(&le, "le.nii", LIMIT).unwrap();
        let b = read_nifti_bytes(&be, "be.nii", LIMIT).unwrap();
        assert_same(&a, &b, 0.0);
    }
}

#[test]
fn nifti_qform_alone_gives_the_same_geometry_as_the_sform() {
    // Right- and left-handed (qfac = -1) oblique grids.
    let g = general_grid();
    let mut flipped_dir = g.direction();
    flipped_dir.set_column(2, &(-g.direction().column(2)));
    let left = resecta_geom::Grid::new(g.dims(), g.spacing(), g.origin(), flipped_dir).unwrap();
    for grid in [g, left] {
        let img = Image::new(grid.clone(), VoxelData::U8(vec![1; grid.len()])).unwrap();
        let mut bytes = nifti_bytes(&img, false).unwrap();
        bytes[254..256].copy_from_slice(&0i16.to_le_bytes()); // sform_code = 0
        let back = read_nifti_bytes(&bytes, "q.nii", LIMIT).unwrap();
        let d = (back.grid().affine() - grid.affine()).abs().max();
        assert!(d < 1e-5, "qform affine off by {d}");
        // Neither → diag(pixdim).
        bytes[252..254].copy_from_slice(&0i16.to_le_bytes());
        let plain = read_nifti_bytes(&bytes, "p.nii", LIMIT).unwrap();
        assert!(plain.grid().is_orthogonal());
        assert!((plain.grid().origin()).norm() == 0.0);
        assert!((plain.grid().spacing()[2] - grid.spacing()[2]).abs() < 1e-6);
    }
}

#[test]
fn nifti_scl_slope_and_inter_give_float_values() {
    let img = &all_types(&oblique_grid())[3]; // i16
    let mut bytes = nifti_bytes(img, false).unwrap();
    bytes[112..116].copy_from_slice(&2f32.to_le_bytes());
    bytes[116..120].copy_from_slice(&(-1f32).to_le_bytes());
    let back = read_nifti_bytes(&bytes, "s.nii", LIMIT).unwrap();
    let VoxelData::F32(v) = back.data() else {
        panic!("expected f32, got {:?}", back.data().scalar_type())
    };
    let VoxelData::I16(orig) = img.data() else {
        unreachable!()
    };
    for (a, &b) in v.iter().zip(orig) {
        assert_eq!(*a, 2.0 * f32::from(b) - 1.0);
    }
}

fn nrrd_with(space: &str, directions: &str, origin: &str) -> Vec<u8> {
    // 2×2×2 big-endian unsigned short, raw.
    let mut b = format!(
        "NRRD0005\n# comment\ntype: unsigned short\ndimension: 3\n{space}sizes: 2 2 2\n\
         {directions}{origin}endian: big\nencoding: raw\n\n"
    )
    .into_bytes();
    for v in 0u16..8 {
        b.extend_from_slice(&(v * 1000).to_be_bytes());
    }
    b
}

#[test]
fn nrrd_spaces_convert_to_ras() {
    let dirs = "space directions: (0.5,0,0) (0,0.75,0) (0,0,2)\n";
    let ras = read_nrrd_bytes(
        &nrrd_with("space: RAS\n", dirs, "space origin: (10,20,30)\n"),
        "ras.nrrd",
        LIMIT,
    )
    .unwrap();
    assert_eq!(ras.grid().origin(), Vec3::new(10.0, 20.0, 30.0));
    assert_eq!(
        ras.grid().index_to_world(Vec3::new(1.0, 1.0, 1.0)),
        Vec3::new(10.5, 20.75, 32.0)
    );
    let VoxelData::U16(v) = ras.data() else {
        panic!()
    };
    assert_eq!(v, &[0, 1000, 2000, 3000, 4000, 5000, 6000, 7000]);
    let lps = read_nrrd_bytes(
        &nrrd_with(
            "space: left-posterior-superior\n",
            dirs,
            "space origin: (10,20,30)\n",
        ),
        "lps.nrrd",
        LIMIT,
    )
    .unwrap();
    assert_eq!(
        lps.grid().index_to_world(Vec3::new(1.0, 1.0, 1.0)),
        Vec3::new(-10.5, -20.75, 32.0)
    );
    let las = read_nrrd_bytes(
        &nrrd_with(
            "space: left-anterior-superior\n",
            dirs,
            "space origin: (10,20,30)\n",
        ),
        "las.nrrd",
        LIMIT,
    )
    .unwrap();
    assert_eq!(las.grid().origin(), Vec3::new(-10.0, 20.0, 30.0));
    // No space: per-axis spacings on identity axes.
    let plain =
        read_nrrd_bytes(&nrrd_with("", "spacings: 1.5 2 3\n", ""), "p.nrrd", LIMIT).unwrap();
    assert_eq!(plain.grid().spacing(), [1.5, 2.0, 3.0]);
}

#[test]
fn nrrd_type_spellings_are_all_understood() {
    for (name, size) in [
        ("uchar", 1),
        ("unsigned char", 1),
        ("uint8_t", 1),
        ("signed char", 1),
        ("short", 2),
        ("signed short int", 2),
        ("ushort", 2),
        ("unsigned short int", 2),
        ("int", 4),
        ("uint", 4),
        ("unsigned int", 4),
        ("float", 4),
        ("double", 8),
    ] {
        let mut b = format!(
            "NRRD0004\ntype: {name}\ndimension: 3\nsizes: 1 1 2\nendian: little\nencoding: raw\n\n"
        )
        .into_bytes();
        b.extend(std::iter::repeat_n(0u8, 2 * size));
        let img = read_nrrd_bytes(&b, "t.nrrd", LIMIT).unwrap();
        assert_eq!(img.data().scalar_type().size(), size, "{name}");
    }
}

fn two_layer_seg() -> Segmentation {
    let grid = general_grid();
    let n = grid.len();
    let l0: Vec<u16> = (0..n)
        .map(|i| {
            if i % 3 == 0 {
                1
            } else if i % 3 == 1 {
                2
            } else {
                0
            }
        })
        .collect();
    let l1: Vec<u16> = (0..n)
        .map(|i| if i % 3 == 2 && i % 2 == 0 { 3 } else { 0 })
        .collect();
    let mut seg = Segmentation::from_label_map(Volume::from_vec(grid.clone(), l0).unwrap());
    seg.layers.push(Volume::from_vec(grid, l1).unwrap());
    let mut s3 = seg.segments[0].clone();
    s3.id = "portal".into();
    s3.name = "Portal vein".into();
    s3.label_value = 3;
    s3.layer = 1;
    s3.color = [0.25, 0.5, 1.0];
    seg.segments.push(s3);
    seg.segments[0].name = "Liver".into();
    seg.segments[1].name = "Tumour".into();
    seg
}

#[test]
fn seg_nrrd_single_layer_round_trips_with_segment_metadata() {
    let dir = tempfile::tempdir().unwrap();
    let grid = oblique_grid();
    let labels: LabelMap = Volume::from_vec(
        grid.clone(),
        (0..grid.len()).map(|i| (i % 4) as u16 * 300).collect(),
    )
    .unwrap();
    let mut seg = Segmentation::from_label_map(labels.clone());
    seg.segments[1].name = "Hepatic vein".into();
    seg.segments[1]
        .extra
        .insert("Tags".into(), "Segmentation.Status:inprogress|".into());
    let path = dir.path().join("s.seg.nrrd");
    write_seg_nrrd(&path, &seg).unwrap();
    let text = std::fs::read(&path).unwrap();
    let end = text.windows(2).position(|w| w == b"\n\n").unwrap();
    let header = String::from_utf8_lossy(&text[..end + 1]);
    assert!(header.contains("Segment1_Name:=Hepatic vein\n"), "{header}");
    assert!(header.contains("Segmentation_MasterRepresentation:=Binary labelmap\n"));
    let back = read_seg_nrrd(&path, LIMIT).unwrap();
    assert_eq!(back.layers.len(), 1);
    assert_eq!(back.layers[0].data(), labels.data());
    assert!((back.grid.affine() - grid.affine()).abs().max() < 1e-9);
    assert_eq!(back.segments.len(), 3);
    let hv = back.segment("Hepatic vein").unwrap();
    assert_eq!(hv.label_value, 600);
    assert_eq!(hv.layer, 0);
    assert_eq!(hv.extra["Tags"], "Segmentation.Status:inprogress|");
    assert_eq!(hv.color, seg.segments[1].color);
    // Extent is recomputed from the data: value 600 occurs over the whole grid.
    assert_eq!(hv.extent, Some([0, 6, 0, 4, 0, 3]));
    assert_eq!(back.to_label_map().unwrap().data(), labels.data());
    // And `read_image` flattens it.
    let img = read_image(&path, LIMIT).unwrap();
    assert_eq!(img.to_label_map().unwrap().data(), labels.data());
}

#[test]
fn seg_nrrd_layers_round_trip_flatten_and_refuse_overlap() {
    let seg = two_layer_seg();
    let bytes = seg_nrrd_bytes(&seg).unwrap();
    let head = String::from_utf8_lossy(&bytes[..400]).into_owned();
    assert!(head.contains("dimension: 4\n") && head.contains("space directions: none ("));
    let back = read_seg_nrrd_bytes(&bytes, "layers.seg.nrrd", LIMIT).unwrap();
    assert_eq!(back.layers.len(), 2);
    assert_eq!(back.layers[0].data(), seg.layers[0].data());
    assert_eq!(back.layers[1].data(), seg.layers[1].data());
    let pv = back.segment("Portal vein").unwrap();
    assert_eq!((pv.id.as_str(), pv.layer, pv.label_value), ("portal", 1, 3));
    assert_eq!(pv.color, [0.25, 0.5, 1.0]);
    // Disjoint layers flatten, each segment keeping its label value.
    let flat = back.to_label_map().unwrap();
    let counts = flat.value_counts();
    let expect: BTreeMap<u16, u64> = [0u16, 1, 2, 3]
        .iter()
        .map(|&v| {
            let c = seg
                .layers
                .iter()
                .map(|l| l.data().iter().filter(|&&x| x == v && v != 0).count() as u64)
                .sum::<u64>();
            (v, c)
        })
        .filter(|&(v, _)| v != 0)
        .collect();
    for (v, c) in expect {
        assert_eq!(counts[&v], c, "label {v}");
    }
    // Overlap between layers is refused.
    let mut over = seg.clone();
    over.layers[1].data_mut()[0] = 3; // voxel 0 is label 1 in layer 0
    let e = over.to_label_map().unwrap_err();
    assert!(
        matches!(e, ErrorKind::Segmentation(ref m) if m.contains("overlap")),
        "{e}"
    );
    // So is one label value in two layers.
    let mut clash = seg.clone();
    clash.segments[2].label_value = 1;
    assert!(matches!(
        clash.to_label_map(),
        Err(ErrorKind::Segmentation(_))
    ));
}

#[test]
fn metaimage_transform_matrix_lists_axis_directions_like_itk() {
    // Header as SimpleITK 2.x writes it for direction columns (cos .3, sin .3, 0),
    // (-sin .3, cos .3, 0), (0, 0, 1); ITK maps index (1,0,0) to LPS
    // (1.4776682445628029, 2.1477601033306697, 3.0).
    let mut b =
        b"ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = True\n\
CompressedData = False\nTransformMatrix = 0.95533648912560598 0.29552020666133955 0 \
-0.29552020666133955 0.95533648912560598 0 0 0 1\nOffset = 1 2 3\nCenterOfRotation = 0 0 0\n\
AnatomicalOrientation = RAI\nElementSpacing = 0.5 0.69999999999999996 2\nDimSize = 4 3 2\n\
ElementType = MET_SHORT\nElementDataFile = LOCAL\n"
            .to_vec();
    for v in 0i16..24 {
        b.extend_from_slice(&(v - 12).to_be_bytes());
    }
    let img = resecta_io::metaimage::read_metaimage_bytes(&b, "itk.mha", LIMIT).unwrap();
    let p = img.grid().index_to_world(Vec3::new(1.0, 0.0, 0.0));
    let want = Vec3::new(-1.4776682445628029, -2.1477601033306697, 3.0);
    assert!((p - want).norm() < 1e-12, "{p}");
    let VoxelData::I16(v) = img.data() else {
        panic!()
    };
    assert_eq!(v[0], -12);
    assert_eq!(v[23], 11);
}

#[test]
fn image_conversions_and_value_ranges() {
    let grid = oblique_grid();
    let n = grid.len();
    let f = Image::new(
        grid.clone(),
        VoxelData::F32((0..n).map(|i| (i % 5) as f32).collect()),
    )
    .unwrap();
    assert_eq!(f.value_range(), Some((0.0, 4.0)));
    let lm = f.to_label_map().unwrap();
    assert_eq!(lm.data()[7], 2);
    let frac = Image::new(grid.clone(), VoxelData::F64(vec![0.5; n])).unwrap();
    assert!(matches!(frac.to_label_map(), Err(ErrorKind::NotLabels(_))));
    let neg = Image::new(grid.clone(), VoxelData::I16(vec![-1; n])).unwrap();
    assert!(matches!(neg.to_label_map(), Err(ErrorKind::NotLabels(_))));
    let big = Image::new(grid.clone(), VoxelData::U32(vec![70_000; n])).unwrap();
    assert!(matches!(big.to_label_map(), Err(ErrorKind::NotLabels(_))));
    assert_eq!(Image::from_label_map(&lm).to_label_map().unwrap(), lm);
    let vol = f.to_volume_f32();
    assert_eq!(Image::from_volume_f32(&vol), f);
    assert!(Image::new(grid, VoxelData::U8(vec![0; n - 1])).is_err());
}
