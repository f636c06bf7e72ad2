//! Training logs: kept prefixes of the CSV and the event file, logs
//! written again from a checkpoint, steps reaching the files.

use sdfl_runtime::train::log::*;
use sdfl_stdlib::value::Optimizer;
use std::time::Duration;

/// The CSV's kept prefix, as [`copy_csv_prefix`] writes it.
fn csv_prefix(text: &[u8], before: usize) -> Vec<u8> {
    let mut out = Vec::new();
    copy_csv_prefix(Some(text), before, &mut out).expect("in memory");
    out
}

/// The event file's kept prefix, as [`copy_events_prefix`] writes it.
fn events_prefix(bytes: &[u8], before: usize) -> Vec<u8> {
    let mut out = Vec::new();
    copy_events_prefix(Some(bytes), before, &mut out).expect("in memory");
    out
}

#[test]
fn the_csv_keeps_whole_rows_in_sequence_before_the_step() {
    let head = format!("{CSV_HEADER}\n");
    let text = format!("{head}1,0.1,0.5,0.01,,\n2,0.2,0.4,0.01,30,0.9\n3,0.3,0.3,0.01,,\n4,0.4,0.");
    let kept = |before| String::from_utf8(csv_prefix(text.as_bytes(), before)).unwrap();
    assert_eq!(
        kept(3),
        format!("{head}1,0.1,0.5,0.01,,\n2,0.2,0.4,0.01,30,0.9\n")
    );
    assert_eq!(kept(1), head);
    // The torn row 4 is dropped whatever the step.
    assert!(kept(100).ends_with("3,0.3,0.3,0.01,,\n"));
    // A foreign file keeps only a header.
    assert_eq!(csv_prefix(b"a,b\n1,2\n", 5), head.as_bytes());
    // Out of order, or a step skipped: kept up to the gap.
    let disordered = format!("{head}2,0,0,0,,\n1,0,0,0,,\n");
    assert_eq!(csv_prefix(disordered.as_bytes(), 5), head.as_bytes());
    let gap = format!("{head}1,0,0,0,,\n3,0,0,0,,\n");
    assert_eq!(
        csv_prefix(gap.as_bytes(), 5),
        format!("{head}1,0,0,0,,\n").as_bytes()
    );
    // A line longer than any row (a file of zeros) ends the prefix.
    let long = format!("{head}1,{},0,0,,\n", "0".repeat(8192));
    assert_eq!(csv_prefix(long.as_bytes(), 5), head.as_bytes());
    assert_eq!(csv_prefix(&[0u8; 100_000], 5), head.as_bytes());
}

fn loss(step: i64) -> Vec<u8> {
    tensorboard::record(&tensorboard::scalars_event(
        1.0,
        step,
        &[("train/loss", 1.0), ("train/lr", 0.1)],
    ))
}

fn scores(step: i64) -> Vec<u8> {
    tensorboard::record(&tensorboard::scalars_event(
        1.0,
        step,
        &[("held_out/psnr", 20.0), ("held_out/ssim", 0.5)],
    ))
}

#[test]
fn the_event_file_keeps_whole_records_in_sequence_before_the_step() {
    let version = tensorboard::record(&tensorboard::version_event(1.0));
    let mut file = [version.clone(), loss(1), loss(2), scores(2), loss(3)].concat();
    file.extend_from_slice(&loss(4)[..7]);
    let kept = |before| {
        let mut out = Vec::new();
        let k = copy_events_prefix(Some(&file[..]), before, &mut out).unwrap();
        (tensorboard::records(&out).len(), k)
    };
    assert_eq!(kept(3), (4, (2, true)));
    assert_eq!(kept(2), (2, (1, false)));
    assert_eq!(kept(1), (1, (0, false)));
    assert_eq!(kept(100), (5, (3, false)));
    assert_eq!(events_prefix(&file, 2), [version.clone(), loss(1)].concat());
    // A step skipped, or scores twice: kept up to there.
    let gap = [version.clone(), loss(1), loss(3)].concat();
    assert_eq!(events_prefix(&gap, 9), [version.clone(), loss(1)].concat());
    let twice = [version.clone(), loss(1), scores(1), scores(1)].concat();
    assert_eq!(
        events_prefix(&twice, 9),
        [version.clone(), loss(1), scores(1)].concat()
    );
    // No version record first: a fresh file.
    let fresh = events_prefix(&loss(1), 5);
    let first = tensorboard::records(&fresh);
    assert_eq!(first.len(), 1);
    assert_eq!(tensorboard::event_step(first[0].1).unwrap(), 0);
    assert_eq!(
        tensorboard::records(&events_prefix(&[0u8; 4096], 5)).len(),
        1
    );
}

#[test]
fn logs_cut_short_are_written_again_from_the_checkpoint() {
    let dir = std::env::temp_dir().join(format!("sdfl-log-rebuild-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let (csv, events, _) = paths(&dir, "t");
    std::fs::write(&csv, format!("{CSV_HEADER}\n1,0.1,0.5,0.01,,\n2,0.2,0.")).unwrap();
    std::fs::create_dir_all(events.parent().unwrap()).unwrap();
    let version = tensorboard::record(&tensorboard::version_event(1.0));
    std::fs::write(&events, [version, loss(1), loss(2)].concat()).unwrap();
    let notes = std::sync::Mutex::new(Vec::new());
    let observer = |e: &TrainEvent<'_>| {
        if let TrainEvent::Note(n) = e {
            notes.lock().unwrap().push(n.to_string());
        }
    };
    let history = History {
        seconds: 5.0,
        held_out: vec![HeldOut {
            step: 3,
            seconds: 3.0,
            psnr: 20.0,
            ssim: 0.5,
            views: 2,
            psnr_in_mask: None,
        }],
    };
    let optimizer = Optimizer {
        lr: 0.01,
        schedule: sdfl_stdlib::value::Schedule::Constant,
        moments: Default::default(),
    };
    let losses = [0.5, 0.4, 0.3, 0.2];
    let log = TrainLog::open(&dir, "t", optimizer, &losses, history, 10, &observer).unwrap();
    log.finish().unwrap();
    let text = std::fs::read_to_string(&csv).unwrap();
    let rows: Vec<&str> = text.lines().skip(1).collect();
    assert_eq!(rows.len(), 4, "{text}");
    let steps: Vec<&str> = rows.iter().map(|r| r.split(',').next().unwrap()).collect();
    assert_eq!(steps, ["1", "2", "3", "4"]);
    // Step 2 without a time, 3 with its evaluation's, 4 the checkpoint's.
    assert!(rows[1].starts_with("2,,0.4,"), "{text}");
    assert!(rows[2].starts_with("3,3.000,0.3,") && rows[2].ends_with(",20,0.5"));
    assert!(rows[3].starts_with("4,5.000,0.2,"), "{text}");
    let bytes = std::fs::read(&events).unwrap();
    let steps: Vec<u64> = tensorboard::records(&bytes)
        .iter()
        .map(|(_, d)| tensorboard::event_step(d).unwrap())
        .collect();
    // Version, 1, 2 (kept), 3 and its scores, 4.
    assert_eq!(steps, [0, 1, 2, 3, 3, 4]);
    let notes = notes.into_inner().unwrap();
    assert_eq!(notes.len(), 2, "{notes:?}");
    assert!(
        notes[0].starts_with("t.metrics.csv: steps 2 to 3 missing"),
        "{notes:?}"
    );
    assert!(
        notes[1].contains("events.out.tfevents.sdfl: step 3 missing"),
        "{notes:?}"
    );
}

#[test]
fn steps_reach_the_files_between_evaluations() {
    let dir = std::env::temp_dir().join(format!("sdfl-log-flush-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let (csv, events, _) = paths(&dir, "t");
    let observer = |_: &TrainEvent<'_>| {};
    let optimizer = Optimizer {
        lr: 0.01,
        schedule: sdfl_stdlib::value::Schedule::Constant,
        moments: Default::default(),
    };
    let mut log =
        TrainLog::open(&dir, "t", optimizer, &[], History::default(), 10, &observer).unwrap();
    let rows = || std::fs::read_to_string(&csv).unwrap().lines().count() - 1;
    let events_len = || std::fs::metadata(&events).unwrap().len();
    // Within the interval nothing more reaches the files...
    log.flush_every = Duration::from_secs(3600);
    log.flush().unwrap();
    let before = events_len();
    log.step(1, 0.5);
    log.step(2, 0.4);
    assert_eq!((rows(), events_len()), (0, before));
    // ...past it, every step before the last (still pending its
    // possible scores) and every event.
    log.flush_every = Duration::ZERO;
    log.step(3, 0.3);
    assert_eq!(rows(), 2);
    assert!(events_len() > before);
    log.finish().unwrap();
    assert_eq!(rows(), 3);
    let _ = std::fs::remove_dir_all(&dir);
}
