use super::*;

#[test]
fn names_compare_by_content() {
    assert!(same("UH", "UH"));
    assert!(!same("UH", "UL"));
    assert!(!same("UH", "UHX"));
    assert!(same("", ""));
    assert!(listed(&["R60", "R61"], "R61"));
    assert!(!listed(&[], "R61"));
}

#[test]
fn pins_print_as_in_the_datasheet() {
    assert_eq!(pin(Port::C, 11).to_string(), "PC11");
    assert_eq!(pin(Port::G, 10).to_string(), "PG10");
}

const BEMF: Board = Board {
    name: "test",
    signals: &[
        signal(pin(B, 11), "BEMF2", Drives, Some("R60")),
        signal(pin(C, 4), "BEMF2", Drives, Some("R61")),
    ],
};

#[test]
fn a_removed_link_frees_its_pin_only() {
    const FREE: Image = Image {
        name: "test",
        boards: &[&BEMF],
        removed: &["R60"],
        uses: &[Use::analog(pin(B, 11), "sensor", 14)],
        peripherals: &[],
        interrupts: &[],
    };
    assert_eq!(check(&FREE), Ok(()));
    const OTHER: Image = Image {
        uses: &[Use::analog(pin(C, 4), "sensor", 5)],
        ..FREE
    };
    assert_eq!(
        check(&OTHER),
        Err(Conflict::Occupied {
            pin: pin(C, 4),
            signal: "BEMF2"
        })
    );
}

#[test]
fn every_board_pin_is_a_real_pin() {
    for board in [NUCLEO_G431RB, IHM08M1] {
        for signal in board.signals {
            assert!(signal.pin.number <= 15, "{} {}", board.name, signal.pin);
            assert!(!signal.name.is_empty());
        }
    }
}
