//! Path classes: a path's events as a name, runs of total internal reflection folded, and the
//! designed path (what the system matrix H models) recognised as the signal.
//!
//! Names follow the stray-light reports of non-sequential ray tracers (a path named by the
//! surfaces it meets): `T(back)`, `R(front)` for Fresnel transmission and partial reflection
//! at a face, `TIR×n` for a run of total internal reflections (any number), `D(top,g1,-1)` for
//! order −1 of the film's first grating at the top vHOE, reflection-type (the light leaves the
//! film on the side it entered, as a reflection hologram's designed orders do), `Dt(…)` for a
//! transmission-type order; a path that ends on the display behind the screen ends in
//! `display-behind`. Cross-coupling reads off the name:
//! `D(top,g1,-1) TIR×n D(bottom,g2,+1)` is light that grating 2 couples in at the bottom vHOE
//! and grating 1 couples out at the top (events run from the camera outward, the reverse of
//! the light's travel).

use crate::paths::{Event, Face, Source};

/// The name of the class that H models: the designed paths (see [`is_signal`]).
pub const SIGNAL: &str = "signal";

/// One element of a folded path: an event, or a run of total internal reflections.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Token {
    /// A single event (never `Tir`).
    Event(Event),
    /// One or more total internal reflections in a row.
    TirRun,
    /// The path ends on the display behind the screen (its last token).
    BehindDisplay,
}

impl Token {
    /// The token's text (`T(back)`, `TIR×n`, `D(top,g1,-1)`).
    pub fn text(self) -> String {
        match self {
            Token::TirRun => "TIR×n".to_string(),
            Token::BehindDisplay => "display-behind".to_string(),
            Token::Event(Event::T(f)) => format!("T({})", f.name()),
            Token::Event(Event::R(f)) => format!("R({})", f.name()),
            Token::Event(Event::Tir(f)) => format!("TIR({})", f.name()),
            Token::Event(Event::Edge(side)) => format!("edge({})", side.name()),
            Token::Event(Event::Scatter(f)) => format!("S({})", f.film_name()),
            Token::Event(Event::D {
                face,
                grating,
                order,
                transmitted,
            }) => format!(
                "{}({},g{},{}{})",
                if transmitted { "Dt" } else { "D" },
                face.film_name(),
                u32::from(grating) + 1,
                if order > 0 { "+" } else { "-" },
                order.unsigned_abs()
            ),
        }
    }
}

impl Token {
    /// The token in the short notation of labels: `Tb`/`Tf` and `Rb`/`Rf` for transmission and
    /// reflection at the back/front face, `~` for a run of total internal reflections,
    /// `Dt1-` for order −1 of grating 1 at the top vHOE, `Db1+` at the bottom vHOE (`Xt`/`Xb`
    /// for a transmission-type order).
    pub fn short(self) -> String {
        let face = |f: Face| match f {
            Face::Front => 'f',
            Face::Back => 'b',
        };
        match self {
            Token::TirRun => "~".to_string(),
            Token::BehindDisplay => "@B".to_string(),
            Token::Event(Event::T(f)) => format!("T{}", face(f)),
            Token::Event(Event::R(f)) => format!("R{}", face(f)),
            Token::Event(Event::Tir(f)) => format!("I{}", face(f)),
            Token::Event(Event::Edge(side)) => format!("E{}", &side.name()[..1]),
            Token::Event(Event::Scatter(f)) => format!("S{}", &f.film_name()[..1]),
            Token::Event(Event::D {
                face: f,
                grating,
                order,
                transmitted,
            }) => format!(
                "{}{}{}{}",
                if transmitted { 'X' } else { 'D' },
                if f == Face::Front { 't' } else { 'b' },
                u32::from(grating) + 1,
                if order > 0 { '+' } else { '-' }
            ),
        }
    }
}

/// The class's short name (see [`Token::short`]), tokens joined by spaces.
pub fn short_name(tokens: &[Token]) -> String {
    tokens
        .iter()
        .map(|t| t.short())
        .collect::<Vec<_>>()
        .join(" ")
}

/// Folds `events` into `out` (cleared first): every run of `Tir` becomes one `TirRun`; a path
/// that ends on the display behind the screen (`source`) ends in `BehindDisplay`.
pub fn fold(events: &[Event], source: Source, out: &mut Vec<Token>) {
    out.clear();
    for &e in events {
        match e {
            Event::Tir(_) => {
                if out.last() != Some(&Token::TirRun) {
                    out.push(Token::TirRun);
                }
            }
            e => out.push(Token::Event(e)),
        }
    }
    if source == Source::BehindDisplay {
        out.push(Token::BehindDisplay);
    }
}

/// The class's name: [`SIGNAL`] for a designed path, else its tokens joined by spaces.
pub fn name(tokens: &[Token]) -> String {
    if is_signal(tokens) {
        return SIGNAL.to_string();
    }
    tokens
        .iter()
        .map(|t| t.text())
        .collect::<Vec<_>>()
        .join(" ")
}

/// True for the paths the designed-path tracer follows (`stscam_tracer::trace`) and H
/// therefore contains: straight through the plate, `T(back) T(front)`, and every replica,
/// `T(back) D(top,gj,-1) [TIR×n | R(…)]… D(bottom,gj,+1) T(front)` with the same grating j at
/// both films (the guided wave reflected at the faces, totally or by Fresnel, in any order).
pub fn is_signal(tokens: &[Token]) -> bool {
    use Event::{D, R, T};
    let [first, middle @ .., last] = tokens else {
        return false;
    };
    if *first != Token::Event(T(Face::Back)) || *last != Token::Event(T(Face::Front)) {
        return false;
    }
    let [top, guided @ .., bottom] = middle else {
        return middle.is_empty();
    };
    let (
        Token::Event(D {
            face: Face::Front,
            grating: j,
            order: -1,
            transmitted: false,
        }),
        Token::Event(D {
            face: Face::Back,
            grating: k,
            order: 1,
            transmitted: false,
        }),
    ) = (*top, *bottom)
    else {
        return false;
    };
    j == k
        && guided
            .iter()
            .all(|t| matches!(t, Token::TirRun | Token::Event(R(_))))
}

#[cfg(test)]
mod tests {
    use super::*;
    use Event::{D, R, T, Tir};
    use Face::{Back, Front};

    fn d(face: Face, grating: u8, order: i8) -> Event {
        D {
            face,
            grating,
            order,
            transmitted: false,
        }
    }

    fn class(events: &[Event]) -> String {
        let mut t = Vec::new();
        fold(events, Source::Display, &mut t);
        name(&t)
    }

    #[test]
    fn designed_paths_are_the_signal_and_others_are_named() {
        assert_eq!(class(&[T(Back), T(Front)]), SIGNAL);
        let replica = [
            T(Back),
            d(Front, 0, -1),
            Tir(Back),
            Tir(Front),
            Tir(Back),
            d(Back, 0, 1),
            T(Front),
        ];
        assert_eq!(class(&replica), SIGNAL);
        // The same replica through another grating pair is cross-coupling, not signal.
        let mut cross = replica;
        cross[5] = d(Back, 1, 1);
        assert_eq!(
            class(&cross),
            "T(back) D(top,g1,-1) TIR×n D(bottom,g2,+1) T(front)"
        );
        // A plate ghost: two Fresnel reflections.
        assert_eq!(
            class(&[T(Back), R(Front), R(Back), T(Front)]),
            "T(back) R(front) R(back) T(front)"
        );
        // A ghost after the out-coupling (Fresnel reflection at the front face on the way
        // out) is not signal.
        let mut ghost = replica.to_vec();
        ghost.insert(6, R(Front));
        ghost.insert(7, R(Back));
        assert!(class(&ghost) != SIGNAL);
        // Wrong orders are not signal, nor the designed order in transmission geometry (the
        // guided wave's second pass through the bottom vHOE after its total reflection).
        let mut wrong = replica;
        wrong[1] = d(Front, 0, 1);
        assert!(class(&wrong) != SIGNAL);
        let mut second_pass = replica;
        second_pass[5] = D {
            face: Back,
            grating: 0,
            order: 1,
            transmitted: true,
        };
        assert_eq!(
            class(&second_pass),
            "T(back) D(top,g1,-1) TIR×n Dt(bottom,g1,+1) T(front)"
        );
        assert_eq!(
            {
                let mut t = Vec::new();
                fold(&cross, Source::Display, &mut t);
                short_name(&t)
            },
            "Tb Dt1- ~ Db2+ Tf"
        );
        // The display behind the screen: its own class, never signal.
        let mut t = Vec::new();
        fold(&[T(Back), T(Front)], Source::BehindDisplay, &mut t);
        assert_eq!(name(&t), "T(back) T(front) display-behind");
        // Runs of TIR fold whatever their length.
        let mut longer = replica.to_vec();
        longer.insert(2, Tir(Front));
        assert_eq!(class(&longer), SIGNAL);
    }
}
