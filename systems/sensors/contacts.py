"""The vehicle's contacts, simulation only (DESIGN.md "Landing is judged physically"): the normal
forces of its legs on the landing platform and on the ground, and of every other contact of the
vehicle, read from the MultibodyPlant's contact results every few plant steps, for the
`ground_truth` output (never read by an onboard system)."""
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.multibody.plant import ContactResults
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import CONTACTS

_FORCES = slice(CONTACTS.slice("legs_platform_force").start,
                CONTACTS.slice("other_contact_force").stop)
_TIMES = slice(CONTACTS.slice("legs_platform_time").start,
               CONTACTS.slice("other_contact_time").stop)
_PEAK = CONTACTS.slice("peak_leg_force")


class Contacts(LeafSystem):
    """Sampled every `period` (a few plant steps: the legs' contacts last tens of milliseconds and
    their force changes by under 1 % per millisecond), faster than the run folders' logging, so
    that no contact and no force peak is lost between two logged samples: the contact times and
    the peak leg force accumulate over every sample.

    Classes of contact, by collision geometry: a leg (one of `legs`) on the platform (`platform`),
    a leg on the ground (`ground`: the geometry fixed to the world), and every other contact of a
    `vehicle` geometry (its body on anything, a leg on the car's body).

    Input  `contact_results`  the MultibodyPlant's ContactResults
    Output `contacts`         CONTACTS layout: normal forces [N] at the last sample
                              (`legs_platform_force`, `legs_ground_force`, `other_contact_force`),
                              time in contact since the start [s] (`legs_platform_time`,
                              `legs_ground_time`, `other_contact_time`: they only grow, so any
                              contact between two samples shows as an increase) and the largest
                              normal force on one leg at any sample so far (`peak_leg_force`
                              [N]).
    """

    def __init__(self, legs, platform, ground, vehicle, period: float):
        super().__init__()
        self._legs = {_key(g): k for k, g in enumerate(legs)}
        self._platform = {_key(g) for g in platform}
        self._ground = {_key(g) for g in ground}
        self._vehicle = {_key(g) for g in vehicle} | set(self._legs)
        self._period = period
        self._results = self.DeclareAbstractInputPort("contact_results",
                                                      AbstractValue.Make(ContactResults()))
        state = self.DeclareDiscreteState(CONTACTS.size)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclareStateOutputPort("contacts", state)

    def _update(self, context, discrete_state):
        results = self._results.Eval(context)
        x = discrete_state.get_mutable_vector().get_mutable_value()  # the state so far
        if not (results.num_point_pair_contacts() or results.num_hydroelastic_contacts()):
            x[_FORCES] = 0.0  # in the air: nothing else changes
            return
        forces, leg_forces = self.normal_forces(results)
        x[_FORCES] = forces
        x[_TIMES] += self._period * (forces > 0.0)
        x[_PEAK] = max(x[_PEAK], leg_forces.max(initial=0.0))

    def normal_forces(self, results) -> tuple[np.ndarray, np.ndarray]:
        """([legs on the platform, legs on the ground, other] summed normal forces [N], the normal
        force on each leg [N]) of one ContactResults."""
        forces, leg_forces = np.zeros(3), np.zeros(len(self._legs))
        for i in range(results.num_point_pair_contacts()):
            info = results.point_pair_contact_info(i)
            pair = info.point_pair()
            # contact_force acts on B; nhat_BA_W points from B into A: B is pushed along -nhat.
            self._add(forces, leg_forces, _key(pair.id_A), _key(pair.id_B),
                      -float(info.contact_force() @ pair.nhat_BA_W))
        for i in range(results.num_hydroelastic_contacts()):
            info = results.hydroelastic_contact_info(i)
            surface = info.contact_surface()
            # F_Ac_W acts on M's body; the face normals point out of N into M.
            normal = sum(surface.area(f) * surface.face_normal(f)
                         for f in range(surface.num_faces()))
            normal = normal / max(np.linalg.norm(normal), 1e-12)
            self._add(forces, leg_forces, _key(surface.id_M()), _key(surface.id_N()),
                      float(info.F_Ac_W().translational() @ normal))
        return forces, leg_forces

    def _add(self, forces, leg_forces, a: int, b: int, normal_force: float) -> None:
        if a not in self._vehicle:
            a, b = b, a
        if a not in self._vehicle or b in self._vehicle:
            return  # not the vehicle's (the car on the ground), or the vehicle on itself
        force = max(normal_force, 0.0)
        leg = self._legs.get(a)
        if leg is not None:
            leg_forces[leg] += force
        kind = 2 if leg is None else 0 if b in self._platform else 1 if b in self._ground else 2
        forces[kind] += force


def _key(geometry_id) -> int:
    return geometry_id.get_value()
