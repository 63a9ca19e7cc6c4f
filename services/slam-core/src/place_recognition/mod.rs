//! Place recognition (ORB-SLAM2's ORBVocabulary and KeyFrameDatabase): a
//! bag-of-words vocabulary over ORB descriptors ([`vocabulary`]) and the
//! keyframe database that finds the keyframes a frame looks like
//! ([`database`]). Relocalisation asks it for candidates (and the loop
//! closer will, for loop candidates); matching by bag of words is the
//! matcher's ([`crate::matcher::match_by_bow`]).
//!
//! Dynamic-object masks apply at feature detection, so features on people
//! never reach a bag-of-words vector: a keyframe's vector is made from the
//! keypoints it kept, after its own segmenter masks.

pub mod database;
pub mod vocabulary;

pub use database::KeyframeDatabase;
pub use vocabulary::{BowVector, FeatureVector, Vocabulary, VocabularyError};
