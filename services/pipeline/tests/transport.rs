//! Transport tests on real iceoryx2 shared memory (two nodes, one process).

use pipeline::transport::{remove_run_files, run_files, Transport};
use shared_types::names::{RunNames, Topic};
use shared_types::{FrameHeader, Route};

fn names(tag: &str) -> RunNames {
    RunNames::new(&format!("t{}-{tag}", std::process::id())).unwrap()
}

#[test]
fn slice_samples_arrive_with_their_header() {
    let n = names("slice");
    let a = Transport::open(&n, "pub").unwrap();
    let b = Transport::open(&n, "sub").unwrap();
    let rx = b.slice_receiver::<FrameHeader>(Topic::Frames).unwrap();
    let rx2 = b.slice_receiver::<FrameHeader>(Topic::Frames).unwrap();
    let tx = a
        .slice_sender::<FrameHeader>(Topic::Frames, 640 * 480 * 5)
        .unwrap();
    let mut s = tx.loan(100).unwrap();
    s.payload_mut()[7] = 42;
    s.user_header_mut().seq = 9;
    tx.publish(s).unwrap();
    let got = rx.next_sample().unwrap().expect("sample delivered");
    assert_eq!(got.user_header().seq, 9);
    assert_eq!(got.payload().len(), 100);
    assert_eq!(got.payload()[7], 42);
    assert_eq!(
        rx2.next_sample()
            .unwrap()
            .expect("second subscriber")
            .user_header()
            .seq,
        9
    );
    drop((got, rx, rx2, tx, a, b));
    remove_run_files(&n).unwrap();
}

#[test]
fn typed_messages_arrive_in_order() {
    let n = names("typed");
    let a = Transport::open(&n, "pub").unwrap();
    let b = Transport::open(&n, "sub").unwrap();
    let rx = b.receiver::<Route>(Topic::Routes).unwrap();
    let tx = a.sender::<Route>(Topic::Routes).unwrap();
    for seq in 0..5 {
        tx.send(Route {
            seq,
            kind: 1,
            ..Default::default()
        })
        .unwrap();
    }
    let got: Vec<u64> = rx.drain().unwrap().iter().map(|r| r.seq).collect();
    assert_eq!(got, vec![0, 1, 2, 3, 4]);
    drop((rx, tx, a, b));
    // iceoryx2 keeps one global management segment per prefix after the
    // last node is gone; the supervisor removes it at the end of a run.
    let left = run_files(&n);
    assert!(
        left.iter()
            .all(|f| f.to_string_lossy().ends_with("global_mgmt")),
        "{left:?}"
    );
    remove_run_files(&n).unwrap();
    assert!(run_files(&n).is_empty());
}

#[test]
fn subscriber_created_after_the_publisher_still_receives() {
    let n = names("late");
    let a = Transport::open(&n, "pub").unwrap();
    let b = Transport::open(&n, "sub").unwrap();
    let tx = a
        .slice_sender::<FrameHeader>(Topic::Masks, 640 * 480)
        .unwrap();
    let c = Transport::open(&n, "other").unwrap();
    let other_tx = c
        .slice_sender::<FrameHeader>(Topic::Masks, 640 * 480)
        .unwrap();
    let own = a.slice_receiver::<FrameHeader>(Topic::Masks).unwrap();
    let rx = b.slice_receiver::<FrameHeader>(Topic::Masks).unwrap();
    let mut s = tx.loan(640 * 480).unwrap();
    s.user_header_mut().seq = 3;
    tx.publish(s).unwrap();
    let got = rx
        .next_sample()
        .unwrap()
        .expect("late subscriber gets the sample");
    assert_eq!(got.user_header().seq, 3);
    drop((got, own, other_tx, tx, rx, a, b, c));
    remove_run_files(&n).unwrap();
}

#[test]
fn the_wakeup_bench_leaves_no_iceoryx2_file_behind() {
    let out = std::env::temp_dir().join(format!("wakeup-{}.json", std::process::id()));
    let child = std::process::Command::new(env!("CARGO_BIN_EXE_wakeup-bench"))
        .args(["--messages", "20", "--out"])
        .arg(&out)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Its three ways each use the prefix `dsl_wakeup<its pid>_<way>_`.
    let prefix = format!("dsl_wakeup{}_", child.id());
    let run = child.wait_with_output().unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let _ = std::fs::remove_file(&out);
    let left = pipeline::transport::prefixed_files(&prefix);
    assert!(left.is_empty(), "left behind: {left:?}");
    let said = String::from_utf8_lossy(&run.stderr);
    assert_eq!(said.matches("removed the bench's").count(), 3, "{said}");
}
