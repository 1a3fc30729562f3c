//! The finger as rapier2d rigid bodies: ground, input crank (carrying the drive inertia), coupler,
//! proximal phalanx and distal phalanx (with its crank). The open chain ground–proximal–distal–
//! coupler–crank is a reduced-coordinate multibody; a revolute impulse joint between the crank and
//! the ground at O1 closes the four-bar loop. The joint springs K1, K2 are
//! force-based position motors; the drive's Coulomb friction and stiction is a velocity motor on the
//! crank joint whose force limit follows a Stribeck curve; the viscous term and the motor torque are
//! applied as a torque on the crank. The object is a fixed ball collider (a vertex is a 0.5 mm edge).

use crate::linkage::{self, A_M, B_M, C_M, L1_M, L2_M};
use rapier2d_f64::prelude::*;

/// Radius of the ball that stands for a vertex (a small-radius edge), m.
pub const VERTEX_RADIUS_M: f64 = 0.0005;
/// Thickness of the phalanx colliders (they lie on the right of the phalanx line), m.
const PHALANX_THICKNESS_M: f64 = 0.004;

/// Transmission friction at the crank.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DriveFriction {
    /// Coulomb (sliding) friction torque, N·m.
    pub coulomb_nm: f64,
    /// Breakaway (stiction) torque at rest, N·m.
    pub stiction_nm: f64,
    /// Stribeck velocity: the friction falls from stiction to Coulomb over this speed, rad/s.
    pub stribeck_rad_per_s: f64,
    /// Viscous coefficient, N·m·s/rad.
    pub viscous_nm_s_per_rad: f64,
}

impl DriveFriction {
    /// No friction at all.
    pub const OFF: Self = Self {
        coulomb_nm: 0.0,
        stiction_nm: 0.0,
        stribeck_rad_per_s: 0.03,
        viscous_nm_s_per_rad: 0.0,
    };
    /// A small geared drive: 0.02 N·m Coulomb, 0.035 N·m breakaway, 0.003 N·m·s/rad viscous.
    pub const REALISTIC: Self = Self {
        coulomb_nm: 0.02,
        stiction_nm: 0.035,
        stribeck_rad_per_s: 0.03,
        viscous_nm_s_per_rad: 0.003,
    };

    /// Dry-friction torque limit at crank speed `w_rad_per_s`, N·m.
    pub fn dry_limit_nm(&self, w_rad_per_s: f64) -> f64 {
        let r = w_rad_per_s / self.stribeck_rad_per_s;
        self.coulomb_nm + (self.stiction_nm - self.coulomb_nm) * (-r * r).exp()
    }
}

/// The object the finger closes on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Object {
    /// No object.
    None,
    /// A fixed ball of this radius centred at this world point (m); a vertex has VERTEX_RADIUS_M.
    Ball {
        /// Centre, m (world frame at O1).
        center_m: [f64; 2],
        /// Radius, m.
        radius_m: f64,
    },
}

/// Engine settings: time step, solver effort, contact behaviour.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EngineSettings {
    /// Physics time step, s.
    pub dt_s: f64,
    /// Solver iterations (substeps) per step.
    pub solver_iterations: usize,
    /// Natural frequency of the contact's position correction, Hz (the contact's stiffness).
    pub contact_hz: f64,
    /// Damping ratio of the contact's position correction.
    pub contact_damping_ratio: f64,
    /// Coefficient of restitution at the object contact.
    pub restitution: f64,
    /// Small viscous damping in each spring joint, N·m·s/rad (structural damping of the links).
    pub joint_damping_nm_s_per_rad: f64,
}

impl Default for EngineSettings {
    fn default() -> Self {
        Self {
            dt_s: 1.0e-4,
            solver_iterations: 8,
            contact_hz: 2000.0,
            contact_damping_ratio: 1.0,
            restitution: 0.3,
            joint_damping_nm_s_per_rad: 2.0e-4,
        }
    }
}

/// Physical parameters of one finger.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FingerParams {
    /// Drive inertia reflected to the crank (motor and gears; the links add their own), kg·m².
    pub drive_inertia_kgm2: f64,
    /// Transmission friction.
    pub friction: DriveFriction,
    /// Friction coefficient at the object contact.
    pub contact_mu: f64,
    /// Time constant of the torque loop (first-order lag from command to motor torque), s.
    pub torque_lag_s: f64,
}

/// One contact between a phalanx and the object, read from the engine.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactPoint {
    /// True on the distal phalanx, false on the proximal one.
    pub distal: bool,
    /// Distance along the touched phalanx from its joint (k2 from O2, or k1 from O1), m.
    pub k_m: f64,
    /// Signed separation reported by the engine (negative: penetration), m.
    pub dist_m: f64,
}

/// The simulated finger and its world.
pub struct Finger {
    world: PhysicsWorld,
    crank: RigidBodyHandle,
    proximal: RigidBodyHandle,
    distal: RigidBodyHandle,
    crank_joint: ImpulseJointHandle,
    prox_collider: ColliderHandle,
    distal_collider: ColliderHandle,
    object_collider: Option<ColliderHandle>,
    params: FingerParams,
    motor_nm: f64,
}

fn v(p: [f64; 2]) -> Vector {
    Vector::new(p[0], p[1])
}

fn angle_of(d: [f64; 2]) -> f64 {
    d[1].atan2(d[0])
}

impl Finger {
    /// Builds the finger at rest (θ1 = π/4, θ2 = 0) with the object.
    pub fn new(params: FingerParams, object: Object, engine: EngineSettings) -> Self {
        let rest = linkage::pose(linkage::THETA01_RAD, linkage::THETA02_RAD)
            .expect("the rest pose closes");
        Self::at_pose(params, object, engine, rest)
    }

    fn at_pose(
        params: FingerParams,
        object: Object,
        engine: EngineSettings,
        p: linkage::Pose,
    ) -> Self {
        let mut world = PhysicsWorld::new();
        world.gravity = Vector::ZERO; // the finger works in a horizontal plane
        let ip = &mut world.integration_parameters;
        ip.dt = engine.dt_s;
        ip.num_solver_iterations = engine.solver_iterations;
        // Length scale in mm: allowed penetration 5 µm, speculative margin 20 µm.
        ip.length_unit = 1.0e-3;
        ip.contact_softness =
            SpringCoefficients::new(engine.contact_hz, engine.contact_damping_ratio);
        ip.static_contact_softness =
            SpringCoefficients::new(engine.contact_hz, engine.contact_damping_ratio);
        // Penetration may be corrected at up to 1 m/s (the default scales with length_unit to 3 mm/s).
        ip.normalized_max_corrective_velocity = 1000.0;
        ip.contact_recycling = false;
        ip.warmstart_joints = true;

        let bodies = &mut world.bodies;
        let ground = bodies.insert(RigidBodyBuilder::fixed());
        // Light aluminium-like links; the crank body carries the drive inertia.
        let link = |mass_kg: f64, len_m: f64| {
            MassProperties::new(
                Vector::new(len_m / 2.0, 0.0),
                mass_kg,
                mass_kg * len_m * len_m / 12.0,
            )
        };
        let dynamic = |angle: f64, at: [f64; 2], mp: MassProperties| {
            RigidBodyBuilder::dynamic()
                .translation(v(at))
                .rotation(angle)
                .additional_mass_properties(mp)
                .can_sleep(false)
                .build()
        };
        let crank = bodies.insert(dynamic(
            p.theta_a_rad,
            [0.0, 0.0],
            MassProperties::new(Vector::ZERO, 0.002, params.drive_inertia_kgm2),
        ));
        let proximal = bodies.insert(dynamic(p.theta1_rad, [0.0, 0.0], link(0.006, L1_M)));
        let distal = bodies.insert(dynamic(
            p.theta1_rad + p.theta2_rad,
            p.o2_m,
            link(0.004, L2_M),
        ));
        let coupler_dir = [p.ob_m[0] - p.oc_m[0], p.ob_m[1] - p.oc_m[1]];
        let coupler = bodies.insert(dynamic(angle_of(coupler_dir), p.oc_m, link(0.003, B_M)));

        // The open chain ground → proximal → distal → coupler → crank is a reduced-coordinate
        // multibody, so a contact sees the articulated inertia (the drive's 1e-4..0.1 kg·m² against
        // links of a few grams: a maximal-coordinate solver lets the heavy crank creep through the
        // contact). Each joint's frame puts coordinate 0 at the rest pose.
        let rel = |from: f64, to: f64| to - from;
        let coupler_angle = angle_of(coupler_dir);
        let revolute = |anchor1: Vector, rest_rad: f64| {
            let mut j: GenericJoint = RevoluteJointBuilder::new()
                .local_anchor1(anchor1)
                .contacts_enabled(false)
                .build()
                .into();
            j.set_local_frame1(rapier2d_f64::math::Pose::new(anchor1, rest_rad));
            j
        };
        let spring = |mut j: GenericJoint, k: f64, target_rad: f64| {
            j.set_motor_model(JointAxis::AngX, MotorModel::ForceBased);
            j.set_motor_position(
                JointAxis::AngX,
                target_rad,
                k,
                engine.joint_damping_nm_s_per_rad,
            );
            j
        };
        let mb = &mut world.multibody_joints;
        mb.insert(
            ground,
            proximal,
            spring(
                revolute(Vector::ZERO, p.theta1_rad),
                linkage::K1_NM_PER_RAD,
                linkage::THETA01_RAD - p.theta1_rad,
            ),
            true,
        )
        .expect("tree joint");
        mb.insert(
            proximal,
            distal,
            spring(
                revolute(Vector::new(L1_M, 0.0), p.theta2_rad),
                linkage::K2_NM_PER_RAD,
                linkage::THETA02_RAD - p.theta2_rad,
            ),
            true,
        )
        .expect("tree joint");
        let phi = -linkage::PHI2_RAD;
        // The coupler's frame is at Oc, so Ob is at +b along it.
        let mut at_ob = revolute(
            Vector::new(C_M * phi.cos(), C_M * phi.sin()),
            rel(p.theta1_rad + p.theta2_rad, coupler_angle),
        );
        at_ob.set_local_frame2(rapier2d_f64::math::Pose::new(Vector::new(B_M, 0.0), 0.0));
        mb.insert(distal, coupler, at_ob, true).expect("tree joint");
        let mut last = revolute(Vector::ZERO, rel(coupler_angle, p.theta_a_rad));
        last.set_local_frame2(rapier2d_f64::math::Pose::new(Vector::new(A_M, 0.0), 0.0));
        mb.insert(coupler, crank, last, true).expect("tree joint");
        // Only the springs' own damping: no default joint damping.
        if let Some((m, _)) = mb.get_mut(MultibodyJointHandle(crank.0)) {
            m.damping_mut().fill(0.0);
        }
        // The loop closes at O1 (crank to ground); its motor is the drive's dry friction: a
        // velocity motor holding the crank still, limited to the friction torque.
        let crank_joint = world.impulse_joints.insert(
            ground,
            crank,
            RevoluteJointBuilder::new()
                .motor_model(MotorModel::ForceBased)
                .motor_velocity(0.0, 1.0e3)
                .motor_max_force(params.friction.dry_limit_nm(0.0))
                .contacts_enabled(false),
            true,
        );

        // Phalanx colliders: boxes whose left face is the phalanx line.
        let finger_groups =
            InteractionGroups::new(Group::GROUP_1, Group::GROUP_2, Default::default());
        let object_groups =
            InteractionGroups::new(Group::GROUP_2, Group::GROUP_1, Default::default());
        let phalanx = |len: f64| {
            ColliderBuilder::cuboid(len / 2.0, PHALANX_THICKNESS_M / 2.0)
                .translation(Vector::new(len / 2.0, -PHALANX_THICKNESS_M / 2.0))
                .density(0.0)
                .friction(params.contact_mu)
                .restitution(engine.restitution)
                .collision_groups(finger_groups)
        };
        let prox_collider =
            world
                .colliders
                .insert_with_parent(phalanx(L1_M), proximal, &mut world.bodies);
        let distal_collider =
            world
                .colliders
                .insert_with_parent(phalanx(L2_M), distal, &mut world.bodies);
        let object_collider = match object {
            Object::None => None,
            Object::Ball { center_m, radius_m } => {
                let body = world
                    .bodies
                    .insert(RigidBodyBuilder::fixed().translation(v(center_m)));
                Some(
                    world.colliders.insert_with_parent(
                        ColliderBuilder::ball(radius_m)
                            .friction(params.contact_mu)
                            .restitution(engine.restitution)
                            .collision_groups(object_groups),
                        body,
                        &mut world.bodies,
                    ),
                )
            }
        };
        Self {
            world,
            crank,
            proximal,
            distal,
            crank_joint,
            prox_collider,
            distal_collider,
            object_collider,
            params,
            motor_nm: 0.0,
        }
    }

    /// Advances one time step with the commanded torque `command_nm` (N·m) at the crank; the motor
    /// torque follows the command through the torque loop's first-order lag.
    pub fn step(&mut self, command_nm: f64) {
        let dt = self.world.integration_parameters.dt;
        let lag = self.params.torque_lag_s;
        let alpha = if lag > 0.0 {
            1.0 - (-dt / lag).exp()
        } else {
            1.0
        };
        self.motor_nm += alpha * (command_nm - self.motor_nm);
        let w = self.crank_speed_rad_per_s();
        let f = self.params.friction;
        let limit = f.dry_limit_nm(w);
        if let Some(j) = self.world.impulse_joints.get_mut(self.crank_joint, false) {
            j.data.set_motor_max_force(JointAxis::AngX, limit);
        }
        let body = &mut self.world.bodies[self.crank];
        body.reset_torques(true);
        body.add_torque(self.motor_nm - f.viscous_nm_s_per_rad * w, true);
        self.world.step();
    }

    /// Motor torque at the crank (after the torque loop), N·m.
    pub fn motor_nm(&self) -> f64 {
        self.motor_nm
    }

    /// Absolute input-crank angle θa (MODEL.md convention), rad.
    pub fn theta_a_rad(&self) -> f64 {
        self.world.bodies[self.crank].rotation().angle()
    }

    /// Crank speed, rad/s.
    pub fn crank_speed_rad_per_s(&self) -> f64 {
        self.world.bodies[self.crank].angvel()
    }

    /// Absolute proximal angle θ1, rad.
    pub fn theta1_rad(&self) -> f64 {
        self.world.bodies[self.proximal].rotation().angle()
    }

    /// Distal angle relative to the proximal phalanx θ2, rad.
    pub fn theta2_rad(&self) -> f64 {
        let d = self.world.bodies[self.distal].rotation().angle();
        let mut t2 = d - self.theta1_rad();
        if t2 > std::f64::consts::PI {
            t2 -= 2.0 * std::f64::consts::PI;
        }
        t2
    }

    /// Loop-closure error: how far the crank's pivot has drifted from O1, m.
    pub fn loop_gap_m(&self) -> f64 {
        self.world.bodies[self.crank].translation().length()
    }

    /// The engine's contact points between the object and the phalanges that touch (separation ≤ 0).
    pub fn contacts(&self) -> Vec<ContactPoint> {
        let mut out = Vec::new();
        let Some(obj) = self.object_collider else {
            return out;
        };
        for (handle, distal) in [(self.distal_collider, true), (self.prox_collider, false)] {
            let Some(pair) = self.world.narrow_phase.contact_pair(handle, obj) else {
                continue;
            };
            let phalanx_first = pair.collider1 == handle;
            let coll = &self.world.colliders[handle];
            let body = &self.world.bodies[if distal { self.distal } else { self.proximal }];
            for m in pair.manifolds() {
                for pt in &m.points {
                    if pt.dist > 0.0 {
                        continue;
                    }
                    // Point on the phalanx's surface, in the world, then along the phalanx.
                    let local = if phalanx_first {
                        pt.local_p1
                    } else {
                        pt.local_p2
                    };
                    let world_pt = *coll.position() * local;
                    let in_body = body.position().inverse() * world_pt;
                    out.push(ContactPoint {
                        distal,
                        k_m: in_body.x,
                        dist_m: pt.dist,
                    });
                }
            }
        }
        out
    }
}
