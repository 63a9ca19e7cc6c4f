//! Zero copy, proven: the subscriber reads the very memory the publisher
//! wrote. After sending, the publisher changes the frame through its own
//! mapping while the subscriber still holds the sample; the subscriber sees
//! the change, which no copy on the path could show. The subscriber's
//! pointer also lies in a /dev/shm mapping of the run.

use pipeline::transport::{remove_run_files, Transport};
use shared_types::names::{RunNames, Topic};
use shared_types::FrameHeader;

const LEN: usize = 640 * 480 * 5;

/// The mapping of /proc/self/maps that contains `addr`, if any.
fn mapping_of(addr: usize) -> Option<String> {
    let maps = std::fs::read_to_string("/proc/self/maps").unwrap();
    maps.lines()
        .find(|l| {
            let range = l.split_whitespace().next().unwrap();
            let (a, b) = range.split_once('-').unwrap();
            let (a, b) = (
                usize::from_str_radix(a, 16).unwrap(),
                usize::from_str_radix(b, 16).unwrap(),
            );
            (a..b).contains(&addr)
        })
        .map(String::from)
}

#[test]
fn subscriber_reads_the_memory_the_publisher_wrote() {
    let names = RunNames::new(&format!("zc{}", std::process::id())).unwrap();
    let publisher_side = Transport::open(&names, "writer").unwrap();
    let subscriber_side = Transport::open(&names, "reader").unwrap();
    let rx = subscriber_side
        .slice_receiver::<FrameHeader>(Topic::Frames)
        .unwrap();
    let tx = publisher_side
        .slice_sender::<FrameHeader>(Topic::Frames, LEN)
        .unwrap();

    let mut sample = tx.loan(LEN).unwrap();
    for (i, b) in sample.payload_mut().iter_mut().enumerate() {
        *b = (i % 251) as u8;
    }
    sample.user_header_mut().seq = 1;
    // The publisher keeps its own pointer to the bytes it wrote.
    let written: *mut u8 = sample.payload_mut().as_mut_ptr();
    tx.publish(sample).unwrap();

    let got = rx.next_sample().unwrap().expect("delivered");
    let read: *const u8 = got.payload().as_ptr();
    assert_eq!(got.payload()[1000], (1000 % 251) as u8);

    // Change the frame after it was sent, through the publisher's pointer.
    // SAFETY: the chunk stays mapped while the subscriber holds the sample;
    // volatile accesses keep the compiler from caching either side.
    unsafe {
        std::ptr::write_volatile(written.add(1000), 0xAB);
        std::ptr::write_volatile(written.add(LEN - 1), 0xCD);
        assert_eq!(
            std::ptr::read_volatile(read.add(1000)),
            0xAB,
            "subscriber sees the publisher's memory"
        );
        assert_eq!(std::ptr::read_volatile(read.add(LEN - 1)), 0xCD);
    }

    // Both pointers are in shared memory of this run's prefix.
    for (who, ptr) in [
        ("publisher", written as usize),
        ("subscriber", read as usize),
    ] {
        let map = mapping_of(ptr).unwrap_or_else(|| panic!("{who} pointer not mapped"));
        assert!(
            map.contains("/dev/shm/") && map.contains(&names.file_prefix()),
            "{who}: {map}"
        );
    }
    drop((got, rx, tx, publisher_side, subscriber_side));
    remove_run_files(&names).unwrap();
}
