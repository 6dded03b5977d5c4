//! The injection workflow's states, events and the one table of transitions between
//! them. The executor (`super::Workflow`) acts in a state and reports what happened as
//! an event; [`next`] says where that leads, and refuses any event a state does not
//! expect, so the workflow cannot wander into an undefined situation. Every transition
//! is logged with its reason ([`Transition`]).

use serde::Serialize;

/// Where the workflow is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum State {
    /// Nothing done yet.
    Start,
    /// Identifying the stacks and mapping the image to the stage.
    Calibrating,
    /// One image of the whole plate, the pipette out of view: where the cells are.
    Surveying,
    /// Choosing the next cell.
    NextCell,
    /// Between cells: checking that the image-to-stage map still holds (the bench
    /// drifts), and mapping the image again if it does not.
    Rechecking,
    /// The stage carries the lifted pipette over the cell and lowers it.
    MovingStage,
    /// Finding the tip and the cell in the image.
    Looking,
    /// A1/A2 under closed-loop control put the tip on the cell's axis.
    Aligning,
    /// A3 advances the tip into the cell until the membrane gives, then to the centre.
    Approaching,
    /// The pressure pulse.
    Injecting,
    /// A3 withdraws the tip.
    Retracting,
    /// Looking at the cell again: dose and viability.
    Verifying,
    /// A clearing pulse into the medium after a suspected clog.
    Clearing,
    /// Pipette retracted, actuators at rest, after a fault.
    Safe,
    /// Every cell done.
    Finished,
    /// Stopped on a fault it is not safe to go on after.
    Stopped,
}

/// What happened in a state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Event {
    /// Begin.
    Begin,
    /// Calibrations loaded or made, and checked.
    Calibrated,
    /// A re-check of the calibrations is due (every N cells, or after a fault).
    Recheck,
    /// The re-check is done: the map held, or it was made again.
    Rechecked,
    /// The cells are known.
    Surveyed,
    /// The feeder stage brought the next cell's field of view under the objective
    /// (a plate larger than the view is served field by field).
    FieldReached,
    /// A cell to do.
    CellChosen,
    /// A cell not to do (already done, or unreachable): recorded as skipped.
    CellSkipped,
    /// No cells left.
    NoMoreCells,
    /// The stage arrived in time.
    StageArrived,
    /// The tip and the cell were found.
    Found,
    /// The cell moved since the survey; the target follows it.
    CellMoved,
    /// The tip is on the cell's axis.
    Aligned,
    /// The membrane gave and the tip reached the target depth.
    Penetrated,
    /// The pulse was applied.
    Pulsed,
    /// The tip is out of the cell.
    Retracted,
    /// The cell lives and took its dose.
    DoseOk,
    /// The cell took too little: the pipette may be clogged.
    DoseLow,
    /// The clearing pulse was applied.
    Cleared,
    /// A fault on this cell (lost tracking, the cell lost, no give, a refusal): the
    /// run can go on with the next cell.
    CellFault,
    /// A fault the run cannot go on after (a broken or blocked pipette, a stage that
    /// missed its deadline, repeated faults).
    Fatal,
    /// The safe state is reached after a cell fault.
    Recovered,
}

/// One step of the log.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Transition {
    /// s, simulated (or device) time.
    pub t: f64,
    /// From.
    pub from: State,
    /// Event.
    pub event: Event,
    /// To.
    pub to: State,
    /// Why, in words (with the numbers).
    pub reason: String,
}

/// The transition table: where `event` in `state` leads, or `None` if the state does
/// not expect it.
pub fn next(state: State, event: Event) -> Option<State> {
    use Event as E;
    use State as S;
    Some(match (state, event) {
        (S::Start, E::Begin) => S::Calibrating,
        (S::Calibrating, E::Calibrated) => S::Surveying,
        (S::Surveying, E::Surveyed) => S::NextCell,
        (S::Surveying, E::FieldReached) => S::Surveying,
        (S::NextCell, E::CellChosen) => S::MovingStage,
        (S::NextCell, E::CellSkipped | E::FieldReached) => S::NextCell,
        (S::NextCell, E::NoMoreCells) => S::Finished,
        (S::NextCell, E::Recheck) => S::Rechecking,
        (S::Rechecking, E::Rechecked) => S::NextCell,
        (S::MovingStage, E::StageArrived) => S::Looking,
        (S::Looking, E::Found | E::CellMoved) => S::Aligning,
        (S::Aligning, E::Aligned) => S::Approaching,
        (S::Approaching, E::Penetrated) => S::Injecting,
        (S::Injecting, E::Pulsed) => S::Retracting,
        (S::Retracting, E::Retracted) => S::Verifying,
        (S::Verifying, E::DoseOk) => S::NextCell,
        (S::Verifying, E::DoseLow) => S::Clearing,
        (S::Clearing, E::Cleared) => S::NextCell,
        (
            S::MovingStage
            | S::Looking
            | S::Aligning
            | S::Approaching
            | S::Injecting
            | S::Retracting
            | S::Verifying
            | S::Clearing,
            E::CellFault,
        ) => S::Safe,
        (S::Safe, E::Recovered) => S::NextCell,
        (
            S::Calibrating
            | S::Surveying
            | S::NextCell
            | S::Rechecking
            | S::MovingStage
            | S::Looking
            | S::Aligning
            | S::Approaching
            | S::Injecting
            | S::Retracting
            | S::Verifying
            | S::Clearing
            | S::Safe,
            E::Fatal,
        ) => S::Stopped,
        _ => return None,
    })
}

/// Every state, for tests and documentation.
pub const STATES: [State; 16] = [
    State::Start,
    State::Calibrating,
    State::Surveying,
    State::NextCell,
    State::Rechecking,
    State::MovingStage,
    State::Looking,
    State::Aligning,
    State::Approaching,
    State::Injecting,
    State::Retracting,
    State::Verifying,
    State::Clearing,
    State::Safe,
    State::Finished,
    State::Stopped,
];

/// Every event.
pub const EVENTS: [Event; 22] = [
    Event::Begin,
    Event::Calibrated,
    Event::Recheck,
    Event::Rechecked,
    Event::Surveyed,
    Event::FieldReached,
    Event::CellChosen,
    Event::CellSkipped,
    Event::NoMoreCells,
    Event::StageArrived,
    Event::Found,
    Event::CellMoved,
    Event::Aligned,
    Event::Penetrated,
    Event::Pulsed,
    Event::Retracted,
    Event::DoseOk,
    Event::DoseLow,
    Event::Cleared,
    Event::CellFault,
    Event::Fatal,
    Event::Recovered,
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_state_is_reachable_from_start_and_every_live_state_can_end() {
        let mut seen = vec![State::Start];
        let mut k = 0;
        while k < seen.len() {
            for e in EVENTS {
                if let Some(s) = next(seen[k], e)
                    && !seen.contains(&s)
                {
                    seen.push(s);
                }
            }
            k += 1;
        }
        for s in STATES {
            assert!(seen.contains(&s), "{s:?} unreachable");
        }
        // The end states accept nothing; every other state can stop on a fatal fault
        // (except Start, which has not touched anything yet).
        for s in STATES {
            let outgoing = EVENTS.iter().filter(|e| next(s, **e).is_some()).count();
            match s {
                State::Finished | State::Stopped => assert_eq!(outgoing, 0, "{s:?}"),
                State::Start => assert_eq!(next(s, Event::Fatal), None),
                _ => assert_eq!(next(s, Event::Fatal), Some(State::Stopped), "{s:?}"),
            }
        }
    }

    #[test]
    fn the_pipette_is_only_pulsed_after_the_membrane_gave() {
        // The only way into Injecting is Approaching --Penetrated-->.
        for s in STATES {
            for e in EVENTS {
                if next(s, e) == Some(State::Injecting) {
                    assert_eq!((s, e), (State::Approaching, Event::Penetrated));
                }
            }
        }
    }

    #[test]
    fn every_fault_while_the_pipette_may_be_near_a_cell_passes_through_the_safe_state() {
        for s in [
            State::MovingStage,
            State::Looking,
            State::Aligning,
            State::Approaching,
            State::Injecting,
            State::Retracting,
            State::Verifying,
        ] {
            assert_eq!(next(s, Event::CellFault), Some(State::Safe));
        }
        assert_eq!(next(State::Safe, Event::Recovered), Some(State::NextCell));
    }
}
