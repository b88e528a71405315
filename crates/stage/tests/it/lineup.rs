//! The lineup at runtime: a puppet added on top is grabbed first, the draw
//! order decides which of two overlapping puppets a contact grabs, and a
//! removed puppet lets go of everything, is no longer hit and keeps its id.

use std::path::Path;

use glam::DVec2;
use puppetry_contact::{Contact, ContactFrame, Phase, SourceId};
use puppetry_stage::config::StageConfig;
use puppetry_stage::{Change, CommandError, Puppet, Stage};
use puppetry_testkit::stage_text::{Gingerbread, STAGE};

/// Two gingerbread puppets on the same spot (1 on top).
fn two() -> StageConfig {
    let text = format!(
        "{STAGE}{}{}",
        Gingerbread::new("under"),
        Gingerbread::new("over")
    );
    StageConfig::parse("lineup-test.toml", &text, Path::new("/")).unwrap()
}

fn touch(stage: &mut Stage, id: u32, phase: Phase) {
    let change = Change::Contacts {
        frame: ContactFrame {
            source: SourceId::new("finger"),
            time: 0.0,
            contacts: vec![Contact::new(id, phase, DVec2::new(640.0, 360.0))],
        },
    };
    stage.apply_change(&change).unwrap();
}

/// Which puppets hold a contact handle now.
fn held(stage: &Stage) -> Vec<u32> {
    stage
        .puppets()
        .iter()
        .filter(|p| !p.handles().is_empty())
        .map(|p| p.id)
        .collect()
}

#[test]
fn the_draw_order_decides_what_a_contact_grabs() {
    let mut stage = Stage::from_config(&two()).unwrap();
    let ids = |s: &Stage| s.on_stage().map(|p| p.id).collect::<Vec<_>>();
    assert_eq!(ids(&stage), [0, 1]);
    touch(&mut stage, 1, Phase::Down);
    assert_eq!(held(&stage), [1], "the topmost puppet is grabbed");
    touch(&mut stage, 1, Phase::Up);

    stage.set_order(&[1, 0]).unwrap();
    assert_eq!(ids(&stage), [1, 0]);
    touch(&mut stage, 2, Phase::Down);
    assert_eq!(held(&stage), [0]);
    touch(&mut stage, 2, Phase::Up);

    for bad in [&[1][..], &[1, 1], &[0, 1, 2], &[0, 7]] {
        let refused = stage.set_order(bad);
        assert!(
            matches!(refused, Err(CommandError::BadOrder { .. })),
            "{bad:?}: {refused:?}"
        );
    }
    assert_eq!(ids(&stage), [1, 0], "a refused order changes nothing");
}

#[test]
fn a_removed_puppet_lets_go_is_not_hit_and_keeps_its_id() {
    let config = two();
    let mut stage = Stage::from_config(&config).unwrap();
    touch(&mut stage, 1, Phase::Down);
    assert_eq!(held(&stage), [1]);
    assert!(stage.puppets()[1].depth().is_some());
    stage.remove_puppet(1).unwrap();
    assert!(stage.puppets()[1].removed());
    assert!(
        stage.puppets()[1].depth().is_none(),
        "a removed puppet gives its depth order's buffers back"
    );
    assert!(held(&stage).is_empty(), "what held it let go");
    // The contact that held it moves on nothing, and lifts cleanly.
    touch(&mut stage, 1, Phase::Move);
    touch(&mut stage, 1, Phase::Up);
    touch(&mut stage, 2, Phase::Down);
    assert_eq!(held(&stage), [0], "the puppet below is hit now");
    assert!(matches!(
        stage.remove_puppet(1),
        Err(CommandError::NoSuchPuppet { .. })
    ));
    assert!(matches!(
        stage.undo(1),
        Err(CommandError::NoSuchPuppet { .. })
    ));
    assert!(matches!(
        stage.set_order(&[0, 1]),
        Err(CommandError::BadOrder { .. })
    ));

    // A puppet added later takes the next id, never the removed one's, and
    // lands on top.
    let entry = config.puppets[0].clone();
    let puppet = Puppet::load(&config, 2, &entry).unwrap();
    let id = stage.add_puppet(puppet, &entry).unwrap();
    assert_eq!(id, 2);
    assert_eq!(stage.on_stage().map(|p| p.id).collect::<Vec<_>>(), [0, 2]);
    touch(&mut stage, 2, Phase::Up);
    touch(&mut stage, 3, Phase::Down);
    assert_eq!(held(&stage), [2]);
    assert!(
        stage.solve().iter().any(|&(p, _)| p == 2),
        "the new puppet solves"
    );
}
