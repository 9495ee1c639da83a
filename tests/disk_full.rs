//! Disk full while logging, without root: the test lowers the running logger's file-size limit
//! (RLIMIT_FSIZE, through prlimit(2)) so its writes fail with EFBIG as on a full disk, then
//! raises it again ("space returns"). The logger must report it once, keep draining its
//! subscribers (a probe on the same stream keeps receiving), write again afterwards, and leave
//! a file that reads back cleanly to its end: every record intact and in order, the gap marked
//! with GAP_BEFORE on the first raw frame after it.

use std::time::Duration;

use taxel_formats::records::Tail;
use taxel_formats::{Record, RecordFileReader};
use taxel_msgs::raw_flags;
use taxel_testkit::pipeline;

/// Sets the soft file-size limit of process `pid` (the hard limit stays as it is).
fn set_fsize_limit(pid: u32, bytes: Option<u64>) {
    let mut old = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: prlimit(2) on our own child with valid pointers.
    let r = unsafe {
        libc::prlimit(
            pid as libc::pid_t,
            libc::RLIMIT_FSIZE,
            std::ptr::null(),
            &mut old,
        )
    };
    assert_eq!(r, 0, "prlimit get: {}", std::io::Error::last_os_error());
    let new = libc::rlimit {
        rlim_cur: bytes.map_or(old.rlim_max, |b| b as libc::rlim_t),
        rlim_max: old.rlim_max,
    };
    // SAFETY: as above.
    let r = unsafe {
        libc::prlimit(
            pid as libc::pid_t,
            libc::RLIMIT_FSIZE,
            &new,
            std::ptr::null_mut(),
        )
    };
    assert_eq!(r, 0, "prlimit set: {}", std::io::Error::last_os_error());
}

#[test]
fn logger_survives_a_full_disk_and_marks_the_gap() {
    let mut p = pipeline!("df");
    let rec = p.path("run.taxrec");
    let rec_s = p.arg("run.taxrec");
    let limit = Duration::from_secs(20);
    const FULL_AT: u64 = 96 * 1024;

    let logger = p.logger("s0", &rec_s, &["--flush-ms", "50"]);
    // The disk "fills up" at FULL_AT bytes.
    set_fsize_limit(p[logger].child.id(), Some(FULL_AT));
    let probe = p.latency(
        "latency",
        "s0",
        &["--stream", "raw", "--json", "--seconds", "6"],
    );
    let publisher = p.publisher_ready("s0", &["--seconds", "8", "sim", "--rate-hz", "1000"]);
    p[logger].wait_for("logger cannot", limit);
    // Let the writer's buffer fill so records are really lost, then free space again.
    std::thread::sleep(Duration::from_millis(2500));
    set_fsize_limit(p[logger].child.id(), None);
    p[logger].wait_for("logger writes again", limit);

    p.finish(publisher, limit);
    p.finish(probe, limit);
    p.stop(&[logger]);
    let log = p[logger].output();

    // Reported once per episode, not per record.
    let errors = log.lines().filter(|l| l.contains("logger cannot")).count();
    assert_eq!(errors, 1, "{log}");
    let resumed = log
        .lines()
        .find(|l| l.contains("logger writes again"))
        .expect("resume line");
    let lost: u64 = resumed
        .split("lost=")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no lost= in {resumed:?}"));
    assert!(
        lost > 0,
        "nothing was lost while the disk was full: {resumed}"
    );

    // The stream stayed alive for everyone else: the probe on the raw stream kept receiving.
    // (Its drop count is printed, not asserted: on a loaded machine a probe can miss frames
    // for reasons of its own; the publisher never blocks, iceoryx2's safe overflow sees to it.)
    let out = p[probe].output();
    let json = out
        .lines()
        .find(|l| l.starts_with('{'))
        .unwrap_or_else(|| panic!("no JSON from the probe:\n{out}"));
    assert!(!json.contains("\"received\": 0,"), "{json}");
    eprintln!("probe on the raw stream meanwhile: {json}");

    // The file reads back cleanly to its end: nothing written before the failure is damaged.
    let size = std::fs::metadata(&rec).expect("record file").len();
    assert!(
        size > FULL_AT,
        "the logger did not write again ({size} bytes)"
    );
    let mut reader = RecordFileReader::open(&rec).expect("open record file");
    let mut seqs = Vec::new();
    let mut gap_marks = Vec::new();
    for r in reader.by_ref() {
        if let Record::Raw(f) = r {
            if f.flags & raw_flags::GAP_BEFORE != 0 {
                gap_marks.push(seqs.len());
            }
            seqs.push(f.seq);
        }
    }
    assert_eq!(reader.tail(), Some(&Tail::Clean), "file damaged");
    assert!(seqs.len() > 1000, "only {} raw frames", seqs.len());
    // Frames in order; every hole is marked: the first frame after it carries GAP_BEFORE,
    // whether the logger lost the records or they never reached it (a subscriber buffer that
    // overflowed on a loaded machine).
    let mut holes = Vec::new();
    for k in 1..seqs.len() {
        assert!(seqs[k] > seqs[k - 1], "out of order at frame {k}");
        if seqs[k] != seqs[k - 1] + 1 {
            holes.push(k);
        }
    }
    let marked: Vec<usize> = holes
        .iter()
        .copied()
        .filter(|h| gap_marks.contains(h))
        .collect();
    assert_eq!(
        marked, holes,
        "a hole without GAP_BEFORE ({lost} records lost, marks {gap_marks:?})"
    );
    assert!(
        !marked.is_empty(),
        "no marked hole although {lost} records were lost (holes {holes:?}, marks {gap_marks:?})"
    );
    // Frames were written after the last marked gap (the logger resumed).
    let last_mark = *marked.last().unwrap_or(&0);
    assert!(
        seqs.len() - last_mark > 500,
        "only {} frames after the gap",
        seqs.len() - last_mark
    );
    eprintln!(
        "disk full: {} raw frames in {size} bytes, holes at {holes:?}, marked {marked:?}, {lost} records lost",
        seqs.len()
    );
}
