//! Planetary bodies: the gravity the IMU feels and the sky the cameras see.

/// Where the mission happens.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Body {
    Moon,
    Mars,
    /// An analogue test site on Earth (the thesis's Mt. Etna campaign).
    Earth,
}

impl Body {
    /// Magnitude of gravity at the surface (IAU/NASA fact-sheet values).
    pub fn gravity_mps2(self) -> f64 {
        match self {
            Body::Moon => 1.62,
            Body::Mars => 3.721,
            Body::Earth => 9.806_65,
        }
    }

    /// Gravity in the world frame (z up).
    pub fn gravity_world_mps2(self) -> nalgebra::Vector3<f64> {
        nalgebra::Vector3::new(0.0, 0.0, -self.gravity_mps2())
    }

    pub fn name(self) -> &'static str {
        match self {
            Body::Moon => "moon",
            Body::Mars => "mars",
            Body::Earth => "earth",
        }
    }
}
