//! The marker shapes, one per series (cycling), as geometry the SVG renderer writes down.

/// A point in pixels.
pub(crate) type P = (f64, f64);

/// The marker shapes, one per series (cycling).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Marker {
    Circle,
    Square,
    TriangleUp,
    Diamond,
    Cross,
    Plus,
    TriangleDown,
    Star,
}

pub(crate) const MARKERS: [Marker; 8] = [
    Marker::Circle,
    Marker::Square,
    Marker::TriangleUp,
    Marker::Diamond,
    Marker::Cross,
    Marker::Plus,
    Marker::TriangleDown,
    Marker::Star,
];

/// A marker's geometry: filled circle, filled polygon, or 2 px strokes.
pub(crate) enum Shape {
    Circle { c: P, r: f64 },
    Polygon(Vec<P>),
    Strokes(Vec<(P, P)>),
}

impl Marker {
    pub(crate) fn shape(self, (x, y): P) -> Shape {
        match self {
            Marker::Circle => Shape::Circle { c: (x, y), r: 4.6 },
            Marker::Square => {
                let h = 4.1;
                Shape::Polygon(vec![(x - h, y - h), (x + h, y - h), (x + h, y + h), (x - h, y + h)])
            }
            Marker::TriangleUp => Shape::Polygon(vec![(x, y - 6.1), (x + 5.6, y + 4.1), (x - 5.6, y + 4.1)]),
            Marker::TriangleDown => Shape::Polygon(vec![(x, y + 6.1), (x - 5.6, y - 4.1), (x + 5.6, y - 4.1)]),
            Marker::Diamond => Shape::Polygon(vec![(x, y - 6.3), (x + 5.1, y), (x, y + 6.3), (x - 5.1, y)]),
            Marker::Cross => {
                let h = 4.5;
                Shape::Strokes(vec![((x - h, y - h), (x + h, y + h)), ((x - h, y + h), (x + h, y - h))])
            }
            Marker::Plus => {
                let h = 5.5;
                Shape::Strokes(vec![((x - h, y), (x + h, y)), ((x, y - h), (x, y + h))])
            }
            Marker::Star => {
                let points = (0..10)
                    .map(|k| {
                        let r = if k % 2 == 0 { 6.6 } else { 2.8 };
                        let a = std::f64::consts::PI * (k as f64) / 5.0;
                        (x + r * a.sin(), y - r * a.cos())
                    })
                    .collect();
                Shape::Polygon(points)
            }
        }
    }
}
