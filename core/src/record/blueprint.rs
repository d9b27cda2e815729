//! The viewer layout sent with every recording (a Rerun blueprint), so `make view` and a live
//! viewer open on it without manual arrangement.
//!
//! Layout (tab "Run", active):
//! - left, two thirds of the width: the 3D world (`world/**`), its eye orbiting the table centre
//!   from the table's far side, above it; the depth image's point cloud is hidden in it (one click
//!   on its eye icon in the blueprint panel shows it);
//! - right column: the camera image with the detection boxes, the depth image, and the map's
//!   metrics over time (`eval/**`: accuracy against ground truth after each view; `explore/**`:
//!   entropy, table coverage, chosen utility).
//!
//! Tab "Timings": per-frame stage timings (`timings/**`). Tab "Events": the text log.
//!
//! The Rust SDK's `rerun::blueprint` builder has no setter for view properties (the 3D eye), so
//! the blueprint is written here archetype by archetype, as the SDK does, into a blueprint store
//! sent with [`rerun::RecordingStream::send_blueprint`] (made active and the application's default).
//! View and container ids are fixed, so a recording's blueprint is the same on every run.

use rerun::external::re_sdk_types::blueprint::archetypes::{
    ContainerBlueprint, EntityBehavior, EyeControls3D, PanelBlueprint, ViewBlueprint, ViewContents, ViewportBlueprint,
};
use rerun::external::re_sdk_types::blueprint::components::{
    ActiveTab, ColumnShare, ContainerKind, Eye3DKind, IncludedContent, PanelState, QueryExpression, RootContainer,
    RowShare, ViewClass,
};
use rerun::external::re_sdk_types::external::uuid::Uuid;
use rerun::log::LogMsg;
use rerun::{EntityPath, RecordingStream, RecordingStreamBuilder};

use super::RecordError;

/// Where the 3D view looks: the table top (z = 0).
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize)]
pub struct TableTop {
    /// Centre of the table top (x, y), metres, world frame.
    pub center: [f64; 2],
    /// Size of the table top (x, y), metres.
    pub size: [f64; 2],
}

/// Entity whose 3D visualisation (the depth point cloud) the 3D view hides by default.
pub const DEPTH_ENTITY: &str = "world/camera/image/depth";

enum Node {
    View { id: Uuid, class: &'static str, name: &'static str, origin: &'static str, contents: Vec<&'static str> },
    Container { id: Uuid, kind: ContainerKind, name: &'static str, children: Vec<Node>, shares: Vec<f32> },
}

impl Node {
    fn path(&self) -> String {
        match self {
            Node::View { id, .. } => format!("view/{id}"),
            Node::Container { id, .. } => format!("container/{id}"),
        }
    }

    fn log(&self, bp: &RecordingStream) -> Result<(), RecordError> {
        match self {
            Node::View { class, name, origin, contents, .. } => {
                let path = self.path();
                let queries = contents.iter().map(|q| QueryExpression((*q).into()));
                log(bp, &format!("{path}/ViewContents"), &ViewContents::new(queries))?;
                log(
                    bp,
                    &path,
                    &ViewBlueprint::new(ViewClass((*class).into())).with_display_name(*name).with_space_origin(*origin),
                )?;
                Ok(())
            }
            Node::Container { kind, name, children, shares, .. } => {
                for c in children {
                    c.log(bp)?;
                }
                let contents: Vec<IncludedContent> =
                    children.iter().map(|c| IncludedContent(c.path().as_str().into())).collect();
                let mut arch = ContainerBlueprint::new(*kind).with_display_name(*name).with_contents(contents);
                if !shares.is_empty() {
                    match kind {
                        ContainerKind::Horizontal => {
                            arch = arch.with_col_shares(shares.iter().map(|&s| ColumnShare(s.into())));
                        }
                        ContainerKind::Vertical => {
                            arch = arch.with_row_shares(shares.iter().map(|&s| RowShare(s.into())));
                        }
                        _ => {}
                    }
                }
                if *kind == ContainerKind::Tabs {
                    if let Some(first) = children.first() {
                        arch = arch.with_active_tab(ActiveTab(first.path().as_str().into()));
                    }
                }
                log(bp, &self.path(), &arch)
            }
        }
    }
}

fn log<AS: ?Sized + rerun::AsComponents>(bp: &RecordingStream, entity: &str, value: &AS) -> Result<(), RecordError> {
    bp.log(entity, value).map_err(|e| RecordError::Log { entity: format!("blueprint {entity}"), reason: e.to_string() })
}

/// Fixed ids: a recording's blueprint does not change between runs.
fn id(n: u128) -> Uuid {
    Uuid::from_u128(0x0b5a_0000_0000_4000_8000_0000_0000_0000 | n)
}

/// The eye of the 3D view: it orbits the table centre, seen from the table's far side to the right
/// (+x, −y of the centre, facing the robot at the origin so the arm does not hide the table),
/// 40° above the table, far enough to frame the table's larger side.
pub fn eye_position(table: &TableTop) -> ([f32; 3], [f32; 3]) {
    let [cx, cy] = table.center;
    let reach = 0.5 * table.size[0].max(table.size[1]) + 0.25;
    let distance = 2.0 * reach;
    let elevation = 40f64.to_radians();
    let azimuth = (-45f64).to_radians();
    let horizontal = distance * elevation.cos();
    let eye = [
        (cx + horizontal * azimuth.cos()) as f32,
        (cy + horizontal * azimuth.sin()) as f32,
        (distance * elevation.sin()) as f32,
    ];
    (eye, [cx as f32, cy as f32, 0.0])
}

/// The blueprint's messages (its own store, `application_id`), ready for `send_blueprint`.
pub fn blueprint_messages(application_id: &str, table: Option<&TableTop>) -> Result<Vec<LogMsg>, RecordError> {
    let err = |e: &dyn std::fmt::Display| RecordError::Log { entity: "blueprint".into(), reason: e.to_string() };
    let app = rerun::ApplicationId::try_from(application_id.to_string()).map_err(|e| err(&e))?;
    let (bp, storage) = RecordingStreamBuilder::new(app)
        .recording_id(rerun::external::re_log_types::RecordingId::random())
        .blueprint()
        .memory()
        .map_err(|e| err(&e))?;
    // The viewer reads blueprint stores on this timeline.
    bp.set_time_sequence("blueprint", 0);

    let world_id = id(1);
    let world = Node::View { id: world_id, class: "3D", name: "World", origin: "world", contents: vec!["$origin/**"] };
    let camera = Node::View {
        id: id(2),
        class: "2D",
        name: "Camera and detections",
        origin: "world/camera/image",
        contents: vec!["$origin/rgb", "$origin/detections"],
    };
    let depth = Node::View {
        id: id(3),
        class: "2D",
        name: "Depth",
        origin: "world/camera/image",
        contents: vec!["$origin/depth"],
    };
    let metrics = Node::View {
        id: id(4),
        class: "TimeSeries",
        name: "Map metrics",
        origin: "/",
        contents: vec!["eval/**", "explore/**"],
    };
    let right = Node::Container {
        id: id(11),
        kind: ContainerKind::Vertical,
        name: "Sensors and metrics",
        children: vec![camera, depth, metrics],
        shares: vec![1.0, 1.0, 1.0],
    };
    let run = Node::Container {
        id: id(12),
        kind: ContainerKind::Horizontal,
        name: "Run",
        children: vec![world, right],
        shares: vec![2.0, 1.0],
    };
    let timings =
        Node::View { id: id(5), class: "TimeSeries", name: "Timings", origin: "timings", contents: vec!["$origin/**"] };
    let events =
        Node::View { id: id(6), class: "TextLog", name: "Events", origin: "log", contents: vec!["$origin/**"] };
    let root_id = id(13);
    let root = Node::Container {
        id: root_id,
        kind: ContainerKind::Tabs,
        name: "objslam",
        children: vec![run, timings, events],
        shares: vec![],
    };
    root.log(&bp)?;

    // The 3D view's properties and its hidden depth cloud.
    if let Some(t) = table {
        let (eye, target) = eye_position(t);
        log(
            &bp,
            &format!("view/{world_id}/EyeControls3D"),
            &EyeControls3D::new()
                .with_kind(Eye3DKind::Orbital)
                .with_position(eye)
                .with_look_target(target)
                .with_eye_up([0.0f32, 0.0, 1.0]),
        )?;
    }
    let depth_path = ViewContents::blueprint_base_visualizer_path_for_entity(world_id, &EntityPath::from(DEPTH_ENTITY));
    log(&bp, &depth_path.to_string(), &EntityBehavior::new().with_visible(false))?;

    log(&bp, "viewport", &ViewportBlueprint::new().with_root_container(RootContainer(root_id.into())))?;
    log(&bp, "selection_panel", &PanelBlueprint::new().with_state(PanelState::Collapsed))?;
    log(&bp, "time_panel", &PanelBlueprint::new().with_state(PanelState::Expanded))?;
    bp.flush_blocking().map_err(|e| err(&e))?;
    Ok(storage.take())
}

/// Send the layout with `stream` (active at once and the application's default).
pub fn send(stream: &RecordingStream, application_id: &str, table: Option<&TableTop>) -> Result<(), RecordError> {
    let msgs = blueprint_messages(application_id, table)?;
    let blueprint_id = msgs
        .iter()
        .find_map(|m| match m {
            LogMsg::SetStoreInfo(info) => Some(info.info.store_id.clone()),
            _ => None,
        })
        .ok_or_else(|| RecordError::Log { entity: "blueprint".into(), reason: "no store info".into() })?;
    stream.send_blueprint(
        msgs,
        rerun::external::re_log_types::BlueprintActivationCommand {
            blueprint_id,
            make_active: true,
            make_default: true,
        },
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eye_looks_at_the_table_from_above() {
        let t = TableTop { center: [0.55, 0.0], size: [0.8, 1.0] };
        let (eye, target) = eye_position(&t);
        assert_eq!(target, [0.55, 0.0, 0.0]);
        assert!(eye[2] > 0.3 && eye[0] > 0.55 && eye[1] < 0.0, "{eye:?}");
        let d = ((eye[0] - 0.55).powi(2) + eye[1].powi(2) + eye[2].powi(2)).sqrt();
        // 2 × (half the larger side + 0.25 m)
        assert!((d - 2.0 * 0.75).abs() < 1e-5, "{d}");
    }

    #[test]
    fn blueprint_has_the_layout_and_the_hidden_depth_cloud() {
        let msgs =
            blueprint_messages("objslam-test", Some(&TableTop { center: [0.5, 0.0], size: [1.0, 1.0] })).unwrap();
        assert!(matches!(msgs.first(), Some(LogMsg::SetStoreInfo(_))));
        let text = format!("{msgs:?}");
        for needle in ["EyeControls3D", "EntityBehavior", "ViewportBlueprint", "ContainerBlueprint", "overrides"] {
            assert!(text.contains(needle), "blueprint lacks {needle}");
        }
    }
}
