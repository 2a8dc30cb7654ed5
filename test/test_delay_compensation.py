"""The delay-compensating controller against independent truths: its prediction through the commands in flight
against a step-by-step simulation of the plant (`RobotinoPlant`) under the commands the robot applied; with no
delay, its plans' first entries against the undelayed loop (`MotionController` alone); its lead, reports and
refusals against hand-worked cases.
"""

from dataclasses import replace

import numpy as np
import pytest

from robotino_geom_mpc.control.delay_compensation import PLAN_CURRENT_MARGIN, DelayCompensatingController
from robotino_geom_mpc.control.motion_controller import ControllerInputError
from robotino_geom_mpc.model.plant import RobotinoPlant
from robotino_geom_mpc.model.speed_loop import WheelSpeedLoop
from robotino_geom_mpc.network.link import LinkParams
from robotino_geom_mpc.loop.command_link import CommandLink
from robotino_geom_mpc.loop.controller_loop import ControllerLoop
from robotino_geom_mpc.loop.events import Now
from robotino_geom_mpc.loop.plan_follower import PlanFollower
from robotino_geom_mpc.offline.lockstep import PreviewRows
from robotino_geom_mpc.offline.networked import NetworkedLoop
from robotino_geom_mpc.params.files import load_params
from robotino_geom_mpc.scenarios import get_scenario

pytestmark = [pytest.mark.unit, pytest.mark.slow]  # closed loops over an emulated link

ROBOT, CONTROL = load_params(None)
TS = CONTROL.period_s


def closed_loop(model, control, plans, link_up, link_down, n, seed=0, interface="voltages"):
    """The offline loop's ticks (`offline.networked`: the controller's loop in lockstep, plans if `plans`, and the
    robot's end of the link) on a plant; per tick the plant's true body state and, per plan, (tick of its first
    action, predicted state there). With ``cmd_vel`` the commands are twists held by the plant's wheel-speed loops.
    """
    reference = get_scenario("paper-circle").make_reference()
    controller = ControllerLoop(model, control, Now(0, 0), lockstep=True, interface=interface, plans=plans)
    previews = PreviewRows(reference, TS, round(TS * 1e9), controller.preview_points, n)
    plant = RobotinoPlant(ROBOT)
    speed_loop = WheelSpeedLoop(ROBOT) if interface == "cmd_vel" else None
    loop = NetworkedLoop(controller, previews, CommandLink(link_up, link_down, seed, PlanFollower(TS) if plans
                                                           else None))
    states, voltages, predictions = [], [], {}
    for k in range(n):
        pose, twist = plant.odometry()
        states.append(plant.body_state)
        before = getattr(controller.plans, "prediction", None)
        command = loop.command(k, pose, twist)
        if getattr(controller.plans, "prediction", None) is not before:
            t_a, predicted = controller.plans.prediction
            predictions[round(t_a / TS)] = np.array(predicted)
        voltages.append(command)
        if speed_loop is None:
            plant.step(command, TS)
        else:
            speed_loop.run(plant, command, TS)
    return np.array(states), np.array(voltages), predictions


def test_prediction_through_in_flight_commands_matches_the_plant():
    # up 20 ms, down 30-50 ms: round trips of 5-7 periods; a lead of 8 has every plan there before it acts
    control = replace(CONTROL, lead_min_periods=8, lead_max_periods=8)
    states, _, predictions = closed_loop(ROBOT, control, True, LinkParams(0.02), LinkParams(0.03, 0.02), 400)
    ticks = [k for k in predictions if 100 <= k < 400]
    assert len(ticks) > 250
    predicted = np.array([predictions[k] for k in ticks])
    true = states[ticks]
    position = np.abs(predicted[:, [0, 2]] - true[:, [0, 2]]).max()
    heading = np.abs(predicted[:, 4] - true[:, 4]).max()
    # eq. (49) under the applied accelerations against eqs. (1-10) under the voltages, 8 periods ahead
    assert position < 3e-6 and heading < 3e-6
    # what a controller that ignores the commands in flight would predict: the measured state, moved at its
    # velocity over the lead; the motion in between is what the prediction has to get right
    stale = np.array([states[k - 8][[0, 2]] + 8 * TS * states[k - 8][[1, 3]] for k in ticks])
    assert np.abs(stale - true[:, [0, 2]]).max() > 100 * position


def test_without_delay_the_plans_first_entries_are_the_undelayed_loops_voltages():
    control = replace(CONTROL, lead_min_periods=0, lead_max_periods=0)
    _, compensated, _ = closed_loop(ROBOT, control, True, LinkParams(), LinkParams(), 300)
    _, undelayed, _ = closed_loop(ROBOT, control, False, LinkParams(), LinkParams(), 300)
    assert np.abs(compensated - undelayed).max() < 1e-12
    assert np.abs(undelayed).max() > 1.0  # the loop did something


def test_without_delay_the_twist_plans_are_the_undelayed_loops_twists_under_its_current_limit():
    # the robustness model (mass x1.2, friction x2) puts the model's currents at the limit in the ramp-in, while
    # the wheel-speed loops draw a third of it: twist plans keep the undelayed loop's limit (no voltage margin)
    model = get_scenario("robustness").controller_model(ROBOT)
    control = replace(CONTROL, lead_min_periods=0, lead_max_periods=0)
    perfect = (LinkParams(), LinkParams(), 160)
    _, compensated, _ = closed_loop(model, control, True, *perfect, interface="cmd_vel")
    _, undelayed, _ = closed_loop(model, control, False, *perfect, interface="cmd_vel")
    assert np.abs(compensated - undelayed).max() < 1e-12
    assert np.abs(undelayed).max() > 0.2  # the loop did something [m/s]
    margin = replace(control, current_limit_a=PLAN_CURRENT_MARGIN * control.current_limit_a)
    _, throttled, _ = closed_loop(model, margin, False, *perfect, interface="cmd_vel")
    assert np.abs(throttled - undelayed).max() > 1e-3  # the limit binds: a margin would change the twists


def test_lead_is_the_round_trips_quantile_within_its_bounds():
    control = replace(CONTROL, lead_min_periods=2, lead_max_periods=9, lead_quantile=0.99)
    controller = DelayCompensatingController(ROBOT, control)
    preview = np.zeros((controller.preview_length, 3))
    X = (0.0,) * 6
    assert controller.plan(0.0, X, preview).times_s[0] == pytest.approx(9 * TS)  # nothing measured: lead_max
    for trip in (3, 4, 5, 4, 3):
        controller.report_receipt(0.0, trip * TS)
    assert controller.plan(TS, X, preview).times_s[0] == pytest.approx(TS + 5 * TS)
    for _ in range(50):
        controller.report_receipt(0.0, 30 * TS)  # far beyond lead_max
    assert controller.plan(2 * TS, X, preview).times_s[0] == pytest.approx(2 * TS + 9 * TS)
    assert controller.statistics().lead_periods == 9


def test_reports_of_what_ran_mark_plans_lost_and_late():
    control = replace(CONTROL, lead_min_periods=2, lead_max_periods=2)
    controller = DelayCompensatingController(ROBOT, control)
    preview = np.zeros((controller.preview_length, 3))
    for k in range(4):
        controller.plan(k * TS, (0.0,) * 6, preview)  # plan k acts from tick k + 2
    controller.report_receipt(0.0, 2 * TS)
    controller.report_applied(2 * TS, 0.0, 0)
    controller.report_applied(3 * TS, 0.0, 1)  # plan 1 was due at tick 3 and did not run
    stats = controller.statistics()
    assert (stats.plans_sent, stats.plans_received, stats.plans_lost) == (4, 1, 1)
    controller.report_receipt(TS, 4 * TS)  # it was late, not lost
    stats = controller.statistics()
    assert (stats.plans_received, stats.plans_lost) == (2, 0)
    controller.report_applied(4 * TS, None)
    assert controller.statistics().exhausted_periods == 1


def test_bad_and_stale_odometry():
    controller = DelayCompensatingController(ROBOT, CONTROL)
    preview = np.zeros((controller.preview_length, 3))
    with pytest.raises(ControllerInputError, match="X"):
        controller.plan(0.0, (np.nan,) + (0.0,) * 5, preview)
    with pytest.raises(ControllerInputError, match="preview"):
        controller.plan(0.0, (0.0,) * 6, preview[:-1])
    assert controller.statistics().plans_sent == 0
    assert controller.plan(TS, (0.0,) * 6, preview) is not None
    assert controller.plan(0.0, (0.0,) * 6, preview) is None  # overtaken on the up-link
    assert controller.plan(TS, (0.0,) * 6, preview) is None  # a duplicate
    assert controller.statistics().odometry_stale == 2


def test_reports_at_epoch_times_name_the_plans_sent():
    """Realtime stamps are epoch times (1.8e9 s, a float's step 238 ns): the basis the robot decodes from a plan's
    header (integer ns) is often not the float the controller planned with, and each report must still name its
    plan (receipts counted, applied entries used in the prediction), as in lockstep at small times.
    """
    from robotino_geom_mpc.ros.plans import applied_message, plan_message, plan_of_message, received_message, \
        take_report

    control = replace(CONTROL, lead_min_periods=2, lead_max_periods=2)
    controller = DelayCompensatingController(ROBOT, control)
    n = controller.preview_length
    first_ns = 1_795_798_331_190_000_123  # a node clock's stamp
    differs, sent = 0, []
    for k in range(40):
        stamp_s = (first_ns + k * 10_000_000) * 1e-9
        preview = np.outer(np.arange(1, n + 1) * TS, [0.3, 0.0, 0.0]) + [k * TS * 0.3, 0.0, 0.0]
        plan = controller.plan(stamp_s, (k * TS * 0.3, 0.3, 0.0, 0.0, 0.0, 0.0), preview)
        robot_plan = plan_of_message(plan_message(plan, "voltages"), TS)  # as the robot decodes it
        differs += robot_plan.basis_s != plan.basis_s
        take_report(controller, received_message(robot_plan.times_s[0] - TS, robot_plan.basis_s, "voltages", True),
                    stamp_s)
        take_report(controller, applied_message(robot_plan.times_s[0], robot_plan.basis_s, 0, robot_plan.entries[0],
                                                "voltages"), stamp_s)
        sent.append(plan)
    assert differs > 5  # the case at issue occurs
    assert controller.statistics().plans_received == len(sent)
    assert controller.statistics().plans_lost == 0
    newest_first = controller.history.newest_first()
    for plan in sent[-10:]:  # each reported period runs the entry the report named
        period = controller.history.period(plan.times_s[0])
        assert controller.history.command(period, newest_first)[2] == plan.entries[0]
