//! Questions about the system's state and those a strategy outside the core asks at a decision
//! step ([`Query`]), answered by [`System::query`] from the session and the map as they stand
//! ([`Answer`]), and the session's own decision as a record ([`Decision`]). The bindings take the
//! question as JSON and return the answers' serde form.

use serde::{Deserialize, Serialize};

use super::{PoseMetrics, Progress, System, SystemError};
use crate::active::{NextView, SessionStop, TableGain};
use crate::explore::{ObjectFeatures, Reachability, Strategy, ViewScore};
use crate::geometry::{rows, PinholeCamera, Se3};

/// One question (JSON: `{"query": "score_views", "utility": "object-driven"}`). The decision-step
/// questions (from `object_features` on) need the camera.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(tag = "query", rename_all = "snake_case", deny_unknown_fields)]
pub enum Query {
    /// The session's Init views.
    InitialViews,
    /// The exploration's [`Progress`].
    Progress,
    /// The camera pose the last frame was mapped with (None before the first frame).
    LastPose,
    /// Pose accuracy over the frames given a true pose ([`PoseMetrics`]; None without them).
    PoseMetrics,
    /// The paper's per-object features, map order.
    ObjectFeatures,
    /// The candidate views the utility strategies would sample around the objects `around` (map
    /// ids; None = every object), not filtered by reachability.
    CandidateViews {
        /// Map object ids.
        #[serde(default)]
        around: Option<Vec<u32>>,
    },
    /// The given views scored with `utility` (object-driven, the paper's f; object-driven-discovery,
    /// f with the run's entropy scope; or expected-gain,
    /// with its motion cost from the current pose). Objects whose s(x) = 0 add nothing unless
    /// `explore_every_object`.
    ScoreViews {
        /// `object-driven`, `object-driven-discovery` or `expected-gain`.
        utility: Strategy,
        /// Score every object, explored or not. Default false.
        #[serde(default)]
        explore_every_object: bool,
    },
    /// The paper's stopping rule now: every object's s(x) = 0, or the budget after Init spent.
    PaperStop,
    /// The discovery extension's candidate views (table cells not known yet, the unexplained
    /// ones first), not filtered by reachability.
    TableCandidateViews,
    /// What each given view would show of the table not known yet.
    TableGain,
    /// The budget reserve's count: discovery views a greedy cover takes (each reachable, each
    /// revealing `discovery_min_new_cells` new weighted cells), at most `limit`.
    TableViewsNeeded {
        /// Most views counted.
        limit: usize,
    },
}

/// A candidate view and the map object it was sampled around.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TargetedView {
    /// The camera pose (4x4, rows, OpenCV axes).
    pub world_from_camera: [[f64; 4]; 4],
    /// The object it was sampled around (None for table views).
    pub target_object: Option<u32>,
}

/// The answer to a [`Query`] (JSON: the value alone).
#[derive(Debug, Clone, Serialize)]
#[serde(untagged)]
pub enum Answer {
    /// [`Query::Progress`].
    Progress(Progress),
    /// [`Query::LastPose`].
    Pose {
        /// 4x4, rows, OpenCV axes.
        world_from_camera: Option<[[f64; 4]; 4]>,
    },
    /// [`Query::PoseMetrics`].
    PoseMetrics(Option<PoseMetrics>),
    /// [`Query::ObjectFeatures`].
    Features(Vec<ObjectFeatures>),
    /// [`Query::InitialViews`], [`Query::CandidateViews`], [`Query::TableCandidateViews`].
    Views(Vec<TargetedView>),
    /// [`Query::ScoreViews`].
    Scores(Vec<ViewScore>),
    /// [`Query::PaperStop`]: why to stop, or None.
    Stop(Option<SessionStop>),
    /// [`Query::TableGain`].
    TableGain(Vec<TableGain>),
    /// [`Query::TableViewsNeeded`].
    Count(usize),
}

/// The session's decision (JSON: `{"action": "move", "world_from_camera", "utility",
/// "candidates"}` or `{"action": "stop", "reason"}`).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "action", rename_all = "snake_case")]
pub enum Decision {
    /// Move the camera.
    Move {
        /// Target pose (4x4, rows, OpenCV axes).
        world_from_camera: [[f64; 4]; 4],
        /// Its utility; None for strategies without one.
        utility: Option<f64>,
        /// Every scored candidate, for recording; empty for baselines.
        candidates: Vec<ScoredView>,
    },
    /// Stop exploring.
    Stop {
        /// Why.
        reason: SessionStop,
    },
}

/// A scored candidate view of a [`Decision`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ScoredView {
    /// Candidate pose (4x4, rows).
    pub world_from_camera: [[f64; 4]; 4],
    /// Its utility; None when not finite.
    pub utility: Option<f64>,
    /// Whether the reachability callback accepted it (None: not asked).
    pub reachable: Option<bool>,
}

impl From<NextView> for Decision {
    fn from(next: NextView) -> Self {
        let finite = |u: f64| u.is_finite().then_some(u);
        match next {
            NextView::Move { world_from_camera, utility, candidates } => Decision::Move {
                world_from_camera: rows(&world_from_camera.to_homogeneous()),
                utility: finite(utility),
                candidates: candidates
                    .iter()
                    .map(|c| ScoredView {
                        world_from_camera: rows(&c.world_from_camera.to_homogeneous()),
                        utility: finite(c.utility),
                        reachable: c.reachable,
                    })
                    .collect(),
            },
            NextView::Stop { reason } => Decision::Stop { reason },
        }
    }
}

/// Where a decision step stands: the camera, the current pose and the views in question.
pub struct StepContext<'a> {
    /// The camera the views are judged with (required by the decision-step questions).
    pub camera: Option<&'a PinholeCamera>,
    /// The camera's current pose (the motion cost of `expected-gain`).
    pub world_from_camera: &'a Se3,
    /// The views to score ([`Query::ScoreViews`], [`Query::TableGain`]).
    pub views: &'a [Se3],
    /// Whether a view can be reached ([`Query::TableViewsNeeded`]).
    pub reachable: &'a dyn Reachability,
}

impl System {
    /// Answers `query` at this decision step; errors name the bad value.
    pub fn query(&self, query: &Query, step: &StepContext<'_>) -> Result<Answer, SystemError> {
        let s = &self.session;
        // The map is built only for the questions that read it (`last_pose` is asked every frame).
        let map = || self.pipeline.map();
        let camera = || step.camera.ok_or(SystemError::MissingCamera);
        let views = |v: Vec<crate::explore::CandidateView>| {
            let targeted = |c: &crate::explore::CandidateView| TargetedView {
                world_from_camera: rows(&c.world_from_camera.to_homogeneous()),
                target_object: c.target_object,
            };
            Answer::Views(v.iter().map(targeted).collect())
        };
        Ok(match query {
            Query::InitialViews => {
                let init = s.initial_views()?;
                Answer::Views(
                    init.iter()
                        .map(|p| TargetedView { world_from_camera: rows(&p.to_homogeneous()), target_object: None })
                        .collect(),
                )
            }
            Query::Progress => Answer::Progress(self.progress()),
            Query::LastPose => Answer::Pose { world_from_camera: self.last_pose.map(|p| rows(&p.to_homogeneous())) },
            Query::PoseMetrics => Answer::PoseMetrics(self.pose_metrics()?),
            Query::ObjectFeatures => Answer::Features(s.object_features(&map(), camera()?)?),
            Query::CandidateViews { around } => views(s.candidate_views(&map(), around.as_deref())?),
            Query::ScoreViews {
                utility: utility @ (Strategy::ObjectDriven | Strategy::ObjectDrivenDiscovery | Strategy::ExpectedGain),
                explore_every_object,
            } => {
                let current = step.world_from_camera;
                Answer::Scores(s.score_views(
                    &map(),
                    camera()?,
                    step.views,
                    *utility,
                    current,
                    *explore_every_object,
                )?)
            }
            Query::ScoreViews { utility, .. } => return Err(SystemError::NotAUtility(*utility)),
            Query::PaperStop => Answer::Stop(s.paper_stop(&map(), camera()?)?),
            Query::TableCandidateViews => views(s.table_candidate_views(&map())?),
            Query::TableGain => Answer::TableGain(s.table_gain(&map(), camera()?, step.views)),
            Query::TableViewsNeeded { limit } => {
                Answer::Count(s.table_views_needed(&map(), camera()?, step.reachable, *limit)?)
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::active::ScoredCandidate;

    #[test]
    fn a_decision_reports_poses_as_rows_and_a_missing_utility_as_none() {
        let pose = Se3::translation(0.1, 0.2, 0.3);
        let candidate = ScoredCandidate { world_from_camera: pose, utility: f64::NEG_INFINITY, reachable: Some(false) };
        let next = NextView::Move { world_from_camera: pose, utility: f64::NAN, candidates: vec![candidate] };
        let json = serde_json::to_value(Decision::from(next)).unwrap();
        assert_eq!(json["action"], "move");
        assert_eq!(json["world_from_camera"][1][3], 0.2);
        assert!(json["utility"].is_null());
        assert!(json["candidates"][0]["utility"].is_null());
        assert_eq!(json["candidates"][0]["reachable"], false);
        let stop = serde_json::to_value(Decision::from(NextView::Stop { reason: SessionStop::MaxViews })).unwrap();
        assert_eq!(stop, serde_json::json!({"action": "stop", "reason": "max_views"}));
    }

    fn empty_system() -> System {
        let table = crate::explore::TableRect { center_m: [0.5, 0.0], size_m: [0.8, 1.2], height_m: 0.0 };
        System::new(Default::default(), Default::default(), None, table).unwrap()
    }

    #[test]
    fn an_empty_system_answers_as_its_session_does() {
        let system = empty_system();
        let camera = PinholeCamera::new(320, 240, 300.0, 300.0, 160.0, 120.0).unwrap();
        let look_down = Se3::from_parts(
            nalgebra::Translation3::new(0.5, 0.0, 0.8),
            nalgebra::UnitQuaternion::from_euler_angles(std::f64::consts::PI, 0.0, 0.0),
        );
        let always = |_: &Se3| true;
        let views = [look_down];
        let step =
            StepContext { camera: Some(&camera), world_from_camera: &look_down, views: &views, reachable: &always };
        let Answer::Views(init) = system.query(&Query::InitialViews, &step).unwrap() else { panic!("views") };
        let expected = system.session().initial_views().unwrap();
        assert_eq!(init.len(), expected.len());
        assert_eq!(init[0].world_from_camera, rows(&expected[0].to_homogeneous()));
        let Answer::Progress(p) = system.query(&Query::Progress, &step).unwrap() else { panic!("progress") };
        assert_eq!((p.views_taken, p.max_views), (0, system.session().max_views()));
        // 2 cm cells over the whole 0.8 m x 1.2 m table, none known yet.
        assert!((p.table_unknown_weight - 40.0 * 60.0).abs() < 1e-9);
        let Answer::TableGain(gain) = system.query(&Query::TableGain, &step).unwrap() else { panic!("gain") };
        assert_eq!(gain, system.session().table_gain(&system.map(), &camera, &views));
        assert!(gain[0].cells > 0.0);
        let Answer::Pose { world_from_camera } = system.query(&Query::LastPose, &step).unwrap() else { panic!("pose") };
        assert_eq!(world_from_camera, None);
        // The decision-step questions need the camera; a strategy without a utility is refused.
        let no_camera = StepContext { camera: None, ..step };
        assert!(matches!(system.query(&Query::PaperStop, &no_camera), Err(SystemError::MissingCamera)));
        let random = Query::ScoreViews { utility: Strategy::Random, explore_every_object: false };
        assert!(matches!(system.query(&random, &step), Err(SystemError::NotAUtility(Strategy::Random))));
    }

    #[test]
    fn grid_cell_states_are_coded_as_bytes() {
        let cells = super::super::GridCells {
            p_in_world: Vec::new(),
            states: vec![
                crate::explore::CellState::Unknown,
                crate::explore::CellState::Free,
                crate::explore::CellState::Occupied,
            ],
        };
        assert_eq!(cells.state_codes(), vec![0, 1, 2]);
    }

    #[test]
    fn queries_parse_from_their_json_names() {
        let q: Query = serde_json::from_str(r#"{"query": "score_views", "utility": "expected-gain"}"#).unwrap();
        assert_eq!(q, Query::ScoreViews { utility: Strategy::ExpectedGain, explore_every_object: false });
        let q: Query = serde_json::from_str(r#"{"query": "candidate_views", "around": [3]}"#).unwrap();
        assert_eq!(q, Query::CandidateViews { around: Some(vec![3]) });
        assert!(serde_json::from_str::<Query>(r#"{"query": "candidate_views", "limit": 1}"#).is_err());
        assert!(serde_json::from_str::<Query>(r#"{"query": "everything"}"#).is_err());
        assert!(serde_json::from_str::<Query>(r#"{"query": "candidate_views", "around": [-1]}"#).is_err());
    }
}
