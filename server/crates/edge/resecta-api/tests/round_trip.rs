//! Messages survive encoding and decoding, with oneofs, optional scalars and bytes intact, and
//! the chunk sizes of the README fit the message limit.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test helpers

use prost::Message;
use resecta_api::v1::{
    ControlGroup, DataType, Delta, EditRequest, ErrorInfo, MoveGroup, RawLabelMapHeader,
    ReplicaAddress, ResectionSurface, RoleMap, SetControlPoint, Snapshot, Surface, SurfaceKind,
    UploadLabelMapRequest, Vec3, Verdict, WatchResponse, edit_request, move_group,
    resection_surface, upload_label_map_request, watch_response,
};

fn round_trip<M: Message + Default + PartialEq + std::fmt::Debug>(m: &M) -> M {
    let bytes = m.encode_to_vec();
    assert_eq!(bytes.len(), m.encoded_len());
    let back = M::decode(bytes.as_slice()).unwrap();
    assert_eq!(&back, m);
    back
}

fn v(x: f64, y: f64, z: f64) -> Vec3 {
    Vec3 { x, y, z }
}

#[test]
fn edit_requests_keep_their_operation() {
    let set = EditRequest {
        session_id: "s-1".into(),
        base_version: 7,
        edit: Some(edit_request::Edit::SetControlPoint(SetControlPoint {
            name: "r1".into(),
            i: 1,
            j: 2,
            point: Some(v(-12.5, 40.25, 1e-3)),
        })),
    };
    let back = round_trip(&set);
    let Some(edit_request::Edit::SetControlPoint(p)) = back.edit else {
        panic!("wrong edit {:?}", back.edit)
    };
    assert_eq!(p.point, Some(v(-12.5, 40.25, 1e-3)));

    let ring = EditRequest {
        edit: Some(edit_request::Edit::MoveGroup(MoveGroup {
            name: "r1".into(),
            selection: Some(move_group::Selection::Ring(0)),
            delta: Some(v(0.0, 0.0, 5.0)),
        })),
        ..Default::default()
    };
    // Ring 0 (the border) is a set oneof, distinct from "no selection".
    let back = round_trip(&ring);
    let Some(edit_request::Edit::MoveGroup(g)) = back.edit else {
        panic!()
    };
    assert_eq!(g.selection, Some(move_group::Selection::Ring(0)));
    let inner = MoveGroup {
        selection: Some(move_group::Selection::Group(ControlGroup::Inner as i32)),
        ..Default::default()
    };
    assert_eq!(round_trip(&inner).selection, inner.selection);

    let undo = EditRequest {
        edit: Some(edit_request::Edit::Undo(Default::default())),
        ..Default::default()
    };
    assert!(matches!(
        round_trip(&undo).edit,
        Some(edit_request::Edit::Undo(_))
    ));
}

#[test]
fn optional_numbers_keep_absent_apart_from_zero() {
    let none = Verdict::default();
    let zero = Verdict {
        min_margin_mm: Some(0.0),
        u: Some(0.0),
        v: Some(0.0),
        point: Some(v(0.0, 0.0, 0.0)),
        ..Default::default()
    };
    assert_eq!(round_trip(&none).min_margin_mm, None);
    assert_eq!(round_trip(&zero).min_margin_mm, Some(0.0));
    assert_ne!(none.encode_to_vec(), zero.encode_to_vec());
    let info = ErrorInfo {
        code: "STALE_VERSION".into(),
        field: "base_version".into(),
        current_plan_version: Some(0),
        replica: None,
    };
    assert_eq!(round_trip(&info).current_plan_version, Some(0));
    let moved = ErrorInfo {
        code: "SESSION_ELSEWHERE".into(),
        replica: Some(ReplicaAddress {
            id: "a@1".into(),
            grpc_address: "10.0.0.7:50051".into(),
            http_url: "http://10.0.0.7:8080".into(),
            lease_remaining_ms: 0,
        }),
        ..Default::default()
    };
    assert_eq!(round_trip(&moved), moved);
}

fn raw_header() -> RawLabelMapHeader {
    RawLabelMapHeader {
        session_id: "0123456789abcdef0123456789abcdef".into(),
        dims: vec![512, 512, 300],
        spacing: vec![0.7, 0.7, 2.5],
        origin: vec![-180.0, -180.0, -400.0],
        direction: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        data_type: DataType::Uint8 as i32,
        roles: Some(RoleMap {
            parenchyma: vec![1],
            tumor: vec![2, 5],
            portal: vec![3],
            hepatic: vec![4],
            vessel: vec![],
        }),
        total_bytes: 512 * 512 * 300,
    }
}

#[test]
fn upload_chunks_fit_the_message_limit() {
    let data: Vec<u8> = (0..resecta_api::MAX_CHUNK_BYTES)
        .map(|i| (i % 251) as u8)
        .collect();
    let first = UploadLabelMapRequest {
        header: Some(upload_label_map_request::Header::Raw(raw_header())),
        data,
    };
    let back = round_trip(&first);
    assert_eq!(back.data.len(), resecta_api::MAX_CHUNK_BYTES);
    assert_eq!(back.data[1000], (1000 % 251) as u8);
    // A full chunk with its header stays within 4 MiB + 64 KiB, the smallest message limit a
    // server may announce.
    assert!(first.encoded_len() <= resecta_api::MAX_CHUNK_BYTES + (64 << 10));
    let later = UploadLabelMapRequest {
        header: None,
        data: vec![9; 17],
    };
    assert_eq!(round_trip(&later).header, None);
}

#[test]
fn watch_events_carry_mesh_bytes_unchanged() {
    // Not a valid RSMS mesh: the API carries the bytes opaquely.
    let mesh: Vec<u8> = b"RSMS".iter().copied().chain(0..=255u8).collect();
    let snapshot = WatchResponse {
        seq: 41,
        plan_version: 3,
        event: Some(watch_response::Event::Snapshot(Snapshot {
            models: vec![Surface {
                name: "parenchyma".into(),
                kind: SurfaceKind::Parenchyma as i32,
                label: 1,
                color: None,
                mesh: mesh.clone(),
            }],
            complete: true,
            ..Default::default()
        })),
    };
    let back = round_trip(&snapshot);
    let Some(watch_response::Event::Snapshot(s)) = back.event else {
        panic!()
    };
    assert_eq!(s.models[0].mesh, mesh);
    assert_eq!(s.models[0].kind(), SurfaceKind::Parenchyma);

    let delta = WatchResponse {
        seq: 42,
        plan_version: 4,
        event: Some(watch_response::Event::Delta(Delta {
            resections: vec![ResectionSurface {
                name: "r1".into(),
                mesh: Some(resection_surface::Mesh::MeshDelta(b"RSDL\x01\x00".to_vec())),
                ..Default::default()
            }],
            removed: vec!["r0".into()],
        })),
    };
    let back = round_trip(&delta);
    let Some(watch_response::Event::Delta(d)) = back.event else {
        panic!()
    };
    assert_eq!(
        d.resections[0].mesh,
        Some(resection_surface::Mesh::MeshDelta(b"RSDL\x01\x00".to_vec()))
    );
}

#[test]
fn unknown_enum_values_decode_without_error() {
    // A newer server may send enum values this client does not know (additive v1 changes).
    let s = Surface {
        kind: 99,
        ..Default::default()
    };
    let back = round_trip(&s);
    assert_eq!(back.kind, 99);
    assert!(SurfaceKind::try_from(back.kind).is_err());
}
