//! A distribution that keeps its secant pairs and received totals in
//! scratch files (`Distributor::spill_in`, what a render under a tight
//! `--memory-budget` asks for) reaches the light of one that keeps them in
//! memory, bit for bit: stills, glossy and sequences, mapped and streamed;
//! leaves nothing in the directory; and a directory it cannot write to
//! fails the frame with an error naming it.

mod common;

use illumnet::archive::Archive;
use illumnet::distribute::{DistributeError, DistributeOptions, Distributor, Lighting};
use illumnet::progress::NoProgress;

#[test]
fn spilled_state_gives_the_light_of_state_in_memory_bit_for_bit() {
    for (name, h) in common::coarse_scenes() {
        let dir = tempfile::tempdir().unwrap();
        let path = common::write_scene(&common::scene_file(name), h, dir.path());
        let want = common::solve_all_frames(&Archive::open(&path).unwrap(), None);
        assert!(want[0].balance.iterations > 3, "{name}: the acceleration has pairs to keep");
        let scratch = tempfile::tempdir().unwrap();
        for (what, archive) in
            [("mapped", Archive::open(&path).unwrap()), ("streamed", Archive::open_streamed(&path, 300).unwrap())]
        {
            let got = common::solve_all_frames(&archive, Some(scratch.path()));
            common::assert_same_light(&want, &got, &format!("{name}, {what}, spilled"));
        }
        // The scratch files are unnamed: nothing is left, even while held.
        assert_eq!(std::fs::read_dir(scratch.path()).unwrap().count(), 0, "{name}: files left");
        eprintln!("{name}: {} frames, {} iterations in frame 0", want.len(), want[0].balance.iterations);
    }
}

#[test]
fn a_scratch_directory_that_cannot_be_written_fails_the_frame_naming_it() {
    let (name, h) = common::coarse_scenes()[0];
    let dir = tempfile::tempdir().unwrap();
    let path = common::write_scene(&common::scene_file(name), h, dir.path());
    let archive = Archive::open(&path).unwrap();
    let v = archive.view();
    let missing = dir.path().join("no such directory");
    let d = Distributor::new(&v, &DistributeOptions::default(), &Lighting::from_view(&v)).unwrap().spill_in(&missing);
    let e = d.frame(0, None, &NoProgress).unwrap_err();
    assert!(matches!(e, DistributeError::Scratch { .. }), "{e:?}");
    let message = e.to_string();
    assert!(message.contains("no such directory") && message.contains("scratch"), "{message}");
}
