//! The supervisor: launches, watches and restarts the services, routes each
//! frame by SLAM's keyframe flag, records every frame's fate and reports
//! per-stage latency. The `dynslam` binary is its command line.

pub mod ablation;
pub mod children;
pub mod default_scene;
pub mod external;
pub mod ignore;
pub mod latency;
pub mod map_files;
pub mod mask_eval;
pub mod mask_record;
pub mod outages;
pub mod outputs;
pub mod plots;
pub mod report;
pub mod ros2_camera;
pub mod run;
pub mod run_dir;
pub mod vocab;
