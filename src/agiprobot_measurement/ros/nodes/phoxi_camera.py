"""The node ``phoxi_camera`` (launched by nodes/phoxi_camera): a simulated PhoXi 3D scanner with the real driver's
ROS interface (all names private).

Frames are rendered from the scene file's objects, the part and the robot's links at their current pose from tf
(:mod:`agiprobot_measurement.sensors.phoxi.renderer`); the device semantics (connection, acquisition, frame ids,
coordinate spaces, files) live in :mod:`agiprobot_measurement.sensors.phoxi.device`. This node only wires
parameters, services and topics, and gives the device the poses from tf (it is the device's ScenePoses).

Services (every handler answers; errors are ``success: false`` with the reason, success is ``Ok``):
  get_device_list, connect_camera, disconnect_camera (std_srvs/Empty), is_connected, is_acquiring (deprecated),
  V2/is_connected, V2/is_acquiring, start_acquisition, stop_acquisition (std_srvs/Empty), V2/start_acquisition,
  V2/stop_acquisition, trigger_image, get_frame, save_frame, V2/save_last_frame, get_hardware_indentification,
  get_supported_capturing_modes, get_api_version, get_firmware_version, V2/set_coordinate_space,
  V2/set_transformation, and the seed's names set_coordinate_space, set_transformation_matrix (same types).
Topics: pointcloud, depth_map, texture, rgb_texture, confidence_map, normal_map, camera_info, /diagnostics (5 s),
  parameter_descriptions / parameter_updates (dynamic_reconfigure).
Parameters: the driver's (scanner_id: "" starts disconnected, a listed id connects at start; frame_id, latch_topics,
  topic_queue_size (the cloud's queue is 1, as the driver's), init_from_config, and the reconfigurable ones of
  sensors/phoxi/reconfigure.py, the driver's cfg) and the simulator's: ~camera_config (config/phoxi_camera.yaml),
  ~model, ~camera_xyz_m, ~camera_rpy_rad, ~parent_frame (override the config file), ~publish_tf (true: publish the
  configured pose on tf; false: take the sensor's pose from tf), ~render_configured_pose (false; true with
  publish_tf false: render at the configured pose, publish nothing on tf: a camera awaiting calibration),
  ~scene (config/scene.yaml), ~robot_description (name of the URDF parameter, "" for no robot), ~hidden_links
  (robot links left out of the frames: a list, or names separated by spaces; default "auto": when the sensor frame
  is a link of the robot description (a scanner on the arm, station tool:=phoxi), the link carrying it, i.e. the
  scanner's own housing, which lens and projector sit on and cannot see; "" renders every link), ~output_dir
  (where relative file names resolve; "" = the node's working directory, as the driver's paths),
  ~allowed_save_dirs (list, or a string of paths separated by spaces or colons: where absolute names may also
  point; default the working directory, ROS_HOME and /tmp), ~frame_buffer_size, ~noise_seed, ~error_model
  (realistic: config/error_models/<name>.yaml, drawn per scanner hw_identification; ideal = noise model only), ~models
  (config/phoxi_models.yaml), ~devices (the scanners listed, default the models file's ``devices``), ~pixel_step
  (1; n > 1: every n-th pixel in both directions, a low-resolution camera with the same field of view that renders
  n^2 times faster, for tests), ~free_run_rate_hz (1.0: frames per second in free run), ~tf_timeout_s (0.5, for the
  sensor's pose when it comes from tf).

Poses at capture time: every new frame asks tf for the sensor's pose then (the newest transform tf has), and the
robot's links are posed at that same tf time, so a scanner on a moving arm renders the scene and the robot as they
were at one instant. That instant is the frame's stamp: every message of the frame carries it (a frame published
again later keeps it), so a client looks the sensor's pose up on tf at the message's stamp and gets exactly the pose
the frame was taken from. With the pose configured (publish_tf true in the scene frame, render_configured_pose) the
stamp is the time of the trigger.

Behaviour as the driver's (RosInterface.cpp, PhoXiInterface.cpp of release 1.8.0): trigger_image triggers and answers
the id, publishing nothing; get_frame(id) publishes (id < 0: triggers first); triggering switches to the software
trigger and starts acquisition; reconfiguring without a scanner is refused (values put back); free run takes frames
that only get_frame(id) publishes. A frame's parts are published when the scanner sends them (``send_<part>``) and
the frame holds them: a file camera listed in ``~devices`` with ``frame_outputs`` (PhoXi Control's example the
driver's tests use has no confidence map) lacks the others, and the driver's warning ("Empty confidence map!") is
logged instead. The simulated scanner's settings start as the parameters, so ``init_from_config``
matters only for trigger_mode and start_acquisition (true: the parameters' go to the scanner at connect; false: the
software trigger that connecting sets stays). ``timeout`` is accepted and has no effect (a frame is rendered while
the service waits).

Files: save_frame and V2/save_last_frame follow the package's file policy (common.files.FileRoot): a leading ``~`` is
$HOME (as the driver); ``..`` and paths outside the allowed folders are refused with a message naming them; an
existing file is replaced atomically (the driver overwrites and its services have no flag for it); ``.praw``/
``.prawf`` are refused ("Unsuccessful save: ... not supported by the simulator", docs/phoxi.md "Raw formats"). The file is written outside the device lock, so a long
export does not hold up the other services.
"""

__all__ = ["PhoxiCameraNode", "main"]

import dataclasses
import os
import threading

import numpy as np
import rospy
import tf2_ros
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from dynamic_reconfigure.server import Server as ReconfigureServer
from phoxi_camera.msg import DeviceConnectionStatus, DeviceInformation, DeviceType, PhoXiSize
from phoxi_camera.srv import (
    ConnectCamera,
    ConnectCameraResponse,
    Empty,
    EmptyResponse,
    GetBool,
    GetBoolResponse,
    GetDeviceList,
    GetDeviceListResponse,
    GetFrame,
    GetFrameResponse,
    GetHardwareIdentification,
    GetHardwareIdentificationResponse,
    GetString,
    GetStringResponse,
    GetSupportedCapturingModes,
    GetSupportedCapturingModesResponse,
    IsAcquiring,
    IsAcquiringResponse,
    IsConnected,
    IsConnectedResponse,
    SaveFrame,
    SaveFrameResponse,
    SaveLastFrame,
    SaveLastFrameResponse,
    SetCoordinatesSpace,
    SetCoordinatesSpaceResponse,
    SetTransformationMatrix,
    SetTransformationMatrixResponse,
    TriggerImage,
    TriggerImageResponse,
)
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import Header
from std_srvs.srv import Empty as StdEmpty
from std_srvs.srv import EmptyResponse as StdEmptyResponse

from agiprobot_measurement.common.config import ConfigError, number, whole
from agiprobot_measurement.errors import AgiprobotError, InternalError
from agiprobot_measurement.ros import phoxi_messages
from agiprobot_measurement.ros.conversions import transform_stamped, transform_to_matrix
from agiprobot_measurement.ros.node import run_node
from agiprobot_measurement.ros.params import file_param, flag, has_param, param, vector_param
from agiprobot_measurement.sensors.error_models import DEFAULT_ERROR_MODEL, load_error_model
from agiprobot_measurement.sensors.phoxi import reconfigure as phoxi_config
from agiprobot_measurement.sensors.phoxi.device import (
    API_VERSION,
    NO_VALUE_SPACE,
    OK,
    SETTING_NAMES,
    PhoxiDevice,
    PhoxiError,
    check_reconfigure_changes,
    default_allowed_save_dirs,
    frame_output,
    load_camera_config,
    overridden_pose,
    transform_from_quaternion,
)
from agiprobot_measurement.sensors.phoxi.models import load_scanner_model, load_simulated_scanners
from agiprobot_measurement.sensors.phoxi.scene_geometry import RobotGeometry, scene_geometry
from agiprobot_measurement.station import load_scene
from agiprobot_measurement.station.urdf_model import UrdfModel

#: what a request can fail with: the device's refusals and bad values (AgiprobotError), and file-system errors (disk
#: full, permissions)
REQUEST_ERRORS = (AgiprobotError, OSError)
DIAGNOSTIC_LEVELS = {"OK": DiagnosticStatus.OK, "WARN": DiagnosticStatus.WARN, "ERROR": DiagnosticStatus.ERROR}


class CheckedReconfigureServer(ReconfigureServer):
    """dynamic_reconfigure's server with every value checked against its parameter's type before anything else:
    its own range clamp compares a string with a bool (a TypeError) and keeps a double for an int parameter, which
    broke every later frame. A wrong type refuses the request with a clear service error and keeps the previous
    values (:func:`check_reconfigure_changes`)."""

    def update_configuration(self, changes):
        return super().update_configuration(check_reconfigure_changes(changes))


def _allowed_save_dirs(value) -> list[str]:
    """``~allowed_save_dirs``: a list of folders, or one string of them separated by spaces, commas or colons."""
    if value in (None, ""):
        return [str(d) for d in default_allowed_save_dirs()]
    if isinstance(value, str):
        value = value.replace(",", " ").replace(":", " ").split()
    if not isinstance(value, list) or not all(isinstance(d, str) and d.strip() for d in value):
        raise ConfigError(f"~allowed_save_dirs: expected a list of folders, got {value!r}")
    return [os.path.expanduser(d) for d in value]


def _subsampled(model, pixel_step: int):
    """``model`` with every resolution divided by ``pixel_step`` (a camera of fewer, larger pixels)."""
    if pixel_step == 1:
        return model
    sizes = {key: (max(8, w // pixel_step), max(8, h // pixel_step)) for key, (w, h) in model.resolutions.items()}
    return dataclasses.replace(model, resolutions=sizes)


def _matrix_from_tf(transform):
    """A requested transformation (geometry_msgs/Transform) as 4x4; refusals are the device's PhoxiError."""
    t, q = transform.translation, transform.rotation
    return transform_from_quaternion([t.x, t.y, t.z], [q.x, q.y, q.z, q.w])


class PhoxiCameraNode:
    def __init__(self):
        self.lock = threading.RLock()
        static = {name: param(f"~{name}", default) for name, default in phoxi_config.STATIC_PARAMETERS.items()}
        for name, value in static.items():
            rospy.set_param(f"~{name}", value)  # so clients and tests find every parameter, given or not
        self.frame_id = str(static["frame_id"])
        self.init_from_config = bool(static["init_from_config"])
        # the simulator's own settings (not the driver's, so not reconfigurable)
        self.free_run_rate_hz = param("~free_run_rate_hz", 1.0, number)
        if not 0.0 < self.free_run_rate_hz <= 30.0:
            raise ConfigError(f"~free_run_rate_hz must be in (0, 30] Hz, got {self.free_run_rate_hz}")

        config = load_camera_config(file_param("~camera_config"))
        model_name = param("~model", "") or config.model
        models_file = file_param("~models")
        # the simulator's speed option: every n-th pixel of the image in both directions (the same field of view)
        pixel_step = param("~pixel_step", 1, whole)
        if pixel_step < 1:
            raise ConfigError(f"~pixel_step must be a positive integer, got {pixel_step}")
        self.model = _subsampled(load_scanner_model(model_name, models_file), pixel_step)
        scanners = [
            dataclasses.replace(scanner, model=_subsampled(scanner.model, pixel_step))
            for scanner in load_simulated_scanners(model_name, models_file, param("~devices", None))
        ]
        self.parent_frame = param("~parent_frame", "") or config.parent_frame
        self.configured_pose = overridden_pose(
            config.pose, vector_param("~camera_xyz_m", 3), vector_param("~camera_rpy_rad", 3)
        )
        self.publish_tf = param("~publish_tf", True, flag)
        # simulation of an uncalibrated camera: render at the configured (true) pose but leave tf to a calibration
        self.render_configured_pose = param("~render_configured_pose", False, flag)
        self.tf_timeout = rospy.Duration(param("~tf_timeout_s", 0.5, number))

        scene = load_scene(file_param("~scene"))
        self.scene_frame = scene.frame_id
        robot = urdf = None
        description_param = param("~robot_description", "robot_description")
        if description_param and has_param(description_param):
            urdf = UrdfModel(param(description_param))
            robot = RobotGeometry(urdf)
            for entry in robot.skipped:
                rospy.logwarn("phoxi_camera: robot mesh not found, left out: %s", entry)
        elif description_param:
            rospy.logwarn("phoxi_camera: no robot description in '%s': frames show the scene only", description_param)
        self.hidden_links = self._hide_links(robot, urdf, param("~hidden_links", "auto"))
        # the driver's paths are relative to the node's working directory (roslaunch: ROS_HOME unless cwd="node")
        output_dir = os.path.expanduser(param("~output_dir", "") or os.getcwd())
        self.device = PhoxiDevice(
            self.model,
            scene_geometry(scene),
            output_dir,
            robot=robot,
            frame_buffer_size=param("~frame_buffer_size", 3, whole),
            allowed_dirs=_allowed_save_dirs(param("~allowed_save_dirs", "")),
            scanners=scanners,
            error_model=load_error_model(param("~error_model", DEFAULT_ERROR_MODEL)),
        )
        self.noise_seed = param("~noise_seed", 0, whole)
        # the configuration as the driver starts it: the cfg's defaults overridden by the node's parameters; the
        # simulated scanner's own settings start as these (so init_from_config changes nothing at the first connect)
        self.config = {name: param(f"~{name}", default) for name, default in phoxi_config.defaults.items()}
        self.device.update_settings(seed=self.noise_seed, **{name: self.config[name] for name in SETTING_NAMES})

        # frame index -> the ROS time its poses refer to (the stamp of its messages)
        self.frame_stamps: dict[int, rospy.Time] = {}
        self._capture_stamp = None
        self.tf_buffer = tf2_ros.Buffer()
        self.tf_listener = tf2_ros.TransformListener(self.tf_buffer)
        self.tf_broadcaster = tf2_ros.StaticTransformBroadcaster()
        if self.publish_tf:
            self._broadcast_pose()

        self.latch, queue = bool(static["latch_topics"]), int(static["topic_queue_size"])
        self.publishers = {
            # the driver's cloud publisher has queue size 1 whatever topic_queue_size says
            name: rospy.Publisher(f"~{name}", kind, queue_size=1 if name == "pointcloud" else queue, latch=self.latch)
            for name, kind in (
                ("pointcloud", PointCloud2),
                ("depth_map", Image),
                ("texture", Image),
                ("rgb_texture", Image),
                ("confidence_map", Image),
                ("normal_map", Image),
                ("camera_info", CameraInfo),
            )
        }
        self.diagnostics = rospy.Publisher("/diagnostics", DiagnosticArray, queue_size=5)

        # as the driver: connect at start only when scanner_id names a scanner, else wait for connect_camera
        scanner_id = str(static["scanner_id"])
        if scanner_id:
            try:
                self._connect(scanner_id)
                rospy.loginfo("phoxi_camera: connected to %s", scanner_id)
            except PhoxiError as exc:
                rospy.logwarn("phoxi_camera: connection to default scanner %s failed: %s", scanner_id, exc)
        if self.device.connected:
            # the reconfigure server below starts from the parameters: give it the scanner's state
            for name, value in (
                ("trigger_mode", self.device.trigger_mode),
                ("start_acquisition", self.device.acquiring),
                ("coordinate_space", self.device.coordinate_space),
            ):
                self.config[name] = value
                rospy.set_param(f"~{name}", value)
        self.reconfigure = CheckedReconfigureServer(phoxi_config, self._reconfigure)

        services = [
            ("get_device_list", GetDeviceList, self.get_device_list),
            ("connect_camera", ConnectCamera, self.connect_camera),
            ("disconnect_camera", StdEmpty, self.disconnect_camera),
            ("is_connected", IsConnected, lambda _r: IsConnectedResponse(connected=self.device.connected)),
            ("is_acquiring", IsAcquiring, lambda _r: IsAcquiringResponse(is_acquiring=self.device.acquiring)),
            (
                "V2/is_connected",
                GetBool,
                lambda _r: GetBoolResponse(value=self.device.connected, message=OK, success=True),
            ),
            (
                "V2/is_acquiring",
                GetBool,
                lambda _r: GetBoolResponse(value=self.device.acquiring, message=OK, success=True),
            ),
            ("start_acquisition", StdEmpty, self.start_acquisition),
            ("stop_acquisition", StdEmpty, self.stop_acquisition),
            ("V2/start_acquisition", Empty, self.start_acquisition_v2),
            ("V2/stop_acquisition", Empty, self.stop_acquisition_v2),
            ("trigger_image", TriggerImage, self.trigger_image),
            ("get_frame", GetFrame, self.get_frame),
            ("save_frame", SaveFrame, self.save_frame),
            ("V2/save_last_frame", SaveLastFrame, self.save_last_frame),
            ("get_hardware_indentification", GetHardwareIdentification, self.get_hardware_identification),
            ("get_supported_capturing_modes", GetSupportedCapturingModes, self.get_supported_capturing_modes),
            # the driver answers both with an empty message, and success even when it has no scanner
            ("get_api_version", GetString, lambda _r: GetStringResponse(value=API_VERSION, message="", success=True)),
            ("get_firmware_version", GetString, self.get_firmware_version),
            ("V2/set_coordinate_space", SetCoordinatesSpace, self.set_coordinate_space),
            ("set_coordinate_space", SetCoordinatesSpace, self.set_coordinate_space),
            ("V2/set_transformation", SetTransformationMatrix, self.set_transformation),
            ("set_transformation_matrix", SetTransformationMatrix, self.set_transformation),
        ]
        self.services = [rospy.Service(f"~{name}", kind, handler) for name, kind, handler in services]

        self.diagnostic_timer = rospy.Timer(rospy.Duration(5.0), lambda _e: self.publish_diagnostics())
        self.publish_diagnostics()
        self.free_run = threading.Thread(target=self._free_run_loop, daemon=True)
        self.free_run.start()
        rospy.loginfo(
            "phoxi_camera: simulated PhoXi Control with %s (%s) in %s at %s, files under %s",
            ", ".join(f"{s.hw_identification} ({s.model.name})" for s in self.device.scanners),
            "connected to " + self.device.hardware_identification if self.device.connected else "not connected",
            self.parent_frame,
            np.round(self.configured_pose[:3, 3], 3).tolist(),
            " or ".join(str(r) for r in self.device.files.roots),
        )

    def _hide_links(self, robot, urdf, value) -> list[str]:
        """``~hidden_links``: remove those links from the rendered robot; "auto" = the link carrying the sensor
        frame when the robot description has it (the scanner's housing on the arm)."""
        if robot is None:
            return []
        if value == "auto":
            joint = urdf.joint_by_child.get(self.frame_id)
            names = [joint.parent] if joint is not None else []
        elif isinstance(value, str):
            names = value.replace(",", " ").split()
        elif isinstance(value, list) and all(isinstance(v, str) for v in value):
            names = list(value)
        else:
            raise ConfigError(f"~hidden_links: expected a list of link names or 'auto', got {value!r}")
        unknown = [name for name in names if name not in urdf.links]
        if unknown:
            raise ConfigError(f"~hidden_links: no such links in the robot description: {', '.join(unknown)}")
        for name in names:
            robot.links.pop(name, None)
        if names:
            rospy.loginfo("phoxi_camera: robot links left out of the frames: %s", ", ".join(names))
        return names

    # ------------------------------------------------------------------------------------ tf, scene poses
    def _broadcast_pose(self):
        self.tf_broadcaster.sendTransform(
            transform_stamped(self.configured_pose, self.parent_frame, self.frame_id, rospy.Time.now())
        )

    def _lookup(self, target, source, timeout, stamp=None):
        return transform_to_matrix(self.tf_buffer.lookup_transform(target, source, stamp or rospy.Time(0), timeout))

    def camera_pose(self):
        """scene frame <- sensor frame at capture time: the newest pose tf has, whose time becomes the frame's
        stamp (see :meth:`link_poses`)."""
        if (self.publish_tf or self.render_configured_pose) and self.parent_frame == self.scene_frame:
            self._capture_stamp = rospy.Time.now()
            return self.configured_pose
        try:
            transform = self.tf_buffer.lookup_transform(self.scene_frame, self.frame_id, rospy.Time(0), self.tf_timeout)
        except tf2_ros.TransformException as exc:
            raise InternalError(f"no pose of {self.frame_id} in {self.scene_frame} on tf: {exc}") from exc
        # a chain of static transforms only has no time (zero): the pose holds at any time, the trigger's included
        stamp = transform.header.stamp
        self._capture_stamp = stamp if not stamp.is_zero() else rospy.Time.now()
        return transform_to_matrix(transform)

    def link_poses(self, link_names):
        """Poses of the robot's links in the scene frame from tf at the sensor pose's time (the newest ones where
        tf has none then); links tf does not know are left out."""
        stamp = self._capture_stamp
        poses, missing = {}, []
        for link in link_names:
            # no waiting: robot_state_publisher keeps tf current, and a robot that is not running must not
            # cost a time-out per link and frame
            try:
                poses[link] = self._lookup(self.scene_frame, link, rospy.Duration(0), stamp)
            except tf2_ros.TransformException:
                try:
                    poses[link] = self._lookup(self.scene_frame, link, rospy.Duration(0))
                except tf2_ros.TransformException:
                    missing.append(link)
        if missing:
            rospy.logwarn_throttle(30.0, "phoxi_camera: no tf for robot links %s: left out of the frame", missing)
        return poses

    # ---------------------------------------------------------------------------------------- frames
    def capture(self, index=-1):
        with self.lock:
            self._capture_stamp = None
            frame = self.device.capture(index, self)
            self._remember_stamp(frame)
            return frame

    def _remember_stamp(self, frame) -> None:
        """Keep the time of a newly taken frame's poses (``_capture_stamp``) for its messages; stamps of frames the
        device no longer holds are dropped."""
        if self._capture_stamp is not None:
            self.frame_stamps[frame.index] = self._capture_stamp
            self._capture_stamp = None
        for index in [i for i in self.frame_stamps if i not in self.device.frames]:
            del self.frame_stamps[index]

    def publish_frame(self, frame):
        with self.lock:
            header = Header(stamp=self.frame_stamps.get(frame.index) or rospy.Time.now(), frame_id=self.frame_id)
            points, normals = frame_output(frame)
            outputs = [("camera_info", lambda: phoxi_messages.camera_info(frame.intrinsics, header))]
            if self._delivered(frame, "point_cloud", "Empty point cloud!"):
                organized = self.config["organized_cloud"]
                outputs.append(
                    (
                        "pointcloud",
                        lambda: phoxi_messages.pointcloud2(points, normals, frame.valid, header, organized),
                    )
                )
            if self._delivered(frame, "depth_map", "Empty depth map!"):
                outputs.append(("depth_map", lambda: phoxi_messages.image(frame.depth_mm, "32FC1", header)))
            if self._delivered(frame, "texture", "Empty texture!"):
                outputs.append(("texture", lambda: phoxi_messages.image(frame.texture, "32FC1", header)))
                outputs.append(("rgb_texture", lambda: phoxi_messages.image(frame.rgb_texture(), "rgb8", header)))
            if self._delivered(frame, "confidence_map", "Empty confidence map!"):
                outputs.append(("confidence_map", lambda: phoxi_messages.image(frame.confidence, "32FC1", header)))
            if self._delivered(frame, "normal_map", "Empty normal map!"):
                outputs.append(("normal_map", lambda: phoxi_messages.image(normals, "32FC3", header)))
            for name, build in outputs:
                publisher = self.publishers[name]
                # a message nobody receives is not worth building, unless it is latched for later subscribers
                if self.latch or publisher.get_num_connections() > 0:
                    self._publish(publisher, build(), frame.index)

    def _delivered(self, frame, part, warning) -> bool:
        """Whether the frame holds ``part``: the scanner sends it (``send_<part>``) and, for a file camera, the
        recording has it; else the driver's warning, as its publishFrame logs for an empty part."""
        if self.config[f"send_{part}"] and part in frame.outputs:
            return True
        rospy.logwarn("phoxi_camera: %s", warning)
        return False

    @staticmethod
    def _publish(publisher, msg, seq):
        # rospy overwrites header.seq with the publisher's own message count when it serialises; setting that
        # count first makes the header carry the frame index, as the real driver's messages do.
        impl = publisher.impl
        impl.acquire()
        try:
            impl.seq = int(seq) - 1
            publisher.publish(msg)
        finally:
            impl.release()

    def _free_run_loop(self):
        """In free-run mode the scanner takes frames one after the other (at most ``~free_run_rate_hz``); as with the
        driver they are published only when asked for by ``get_frame(id)``."""
        period = 1.0 / self.free_run_rate_hz
        try:
            while not rospy.is_shutdown():
                with self.lock:
                    running = self.device.free_running()
                if not running:
                    rospy.sleep(0.1)
                    continue
                started = rospy.get_time()
                try:
                    with self.lock:
                        if self.device.free_running():  # the mode may have changed while waiting for the lock
                            self._capture_stamp = None
                            self._remember_stamp(self.device.capture_free_run(self))
                except REQUEST_ERRORS as exc:
                    rospy.logwarn_throttle(10.0, "phoxi_camera: free run: %s", exc)
                rospy.sleep(max(0.0, period - (rospy.get_time() - started)))
        except rospy.ROSException:  # shutdown while sleeping or publishing
            return

    # -------------------------------------------------------------------------------------- services
    def get_device_list(self, _request):
        with self.lock:
            scanners, current = self.device.device_list(), self.device.current
        infos = []
        for scanner in scanners:
            # a scanner this node holds is occupied for everybody else, as PhoXi Control reports it
            status = DeviceConnectionStatus.Occupied if scanner is current else DeviceConnectionStatus.Ready
            info = DeviceInformation(
                name=scanner.name,
                type=DeviceType(type=DeviceType.PhoXiScanner),
                hwIdentification=scanner.hw_identification,
                IPaddress=scanner.ip_address,
                status=DeviceConnectionStatus(status=status),
                firmwareVersion=scanner.firmware_version,
            )
            if hasattr(info, "variant"):  # release 1.8.0's fields
                info.variant, info.isAlpha = scanner.variant, scanner.is_alpha
            infos.append(info)
        return GetDeviceListResponse(
            len=len(infos),
            out=[s.hw_identification for s in scanners],
            device_information_list=infos,
            message=OK,
            success=True,
        )

    def get_firmware_version(self, _request):
        with self.lock:
            current = self.device.current
        if current is None:  # the driver: the exception's message, success nevertheless
            return GetStringResponse(value="", message="No scanner connected", success=True)
        return GetStringResponse(value=current.firmware_version, message="", success=True)

    def _call(self, action):
        """{success, message} of ``action()`` for a response; a refusal becomes the message."""
        try:
            with self.lock:
                action()
        except REQUEST_ERRORS as exc:
            return {"success": False, "message": str(exc)}
        finally:
            self.publish_diagnostics()
        return {"success": True, "message": OK}

    def _connect(self, name):
        """The driver's connectCamera: connect (software trigger, acquisition started); with ``init_from_config`` the
        node's configuration then goes to the scanner (trigger mode and acquisition included), else the
        configuration is read from the scanner (call :meth:`_sync_reconfigure` afterwards, without the lock)."""
        with self.lock:
            self.device.connect(name)
            if self.init_from_config:
                self.device.reconfigure(self.config, -1, previous=self.config)

    def _sync_reconfigure(self):
        """Show the scanner's trigger mode, acquisition and coordinate space in the dynamic_reconfigure values, as the
        driver updates them after connecting, triggering and switching. Never call it holding ``self.lock``: the
        reconfigure server's lock is taken first there."""
        server = getattr(self, "reconfigure", None)
        with self.lock:
            if server is None or not self.device.connected:
                return
            state = {
                "trigger_mode": self.device.trigger_mode,
                "start_acquisition": self.device.acquiring,
                "coordinate_space": self.device.coordinate_space,
            }
            changes = {name: value for name, value in state.items() if self.config.get(name) != value}
        if changes:
            server.update_configuration(changes)

    def connect_camera(self, request):
        result = self._call(lambda: self._connect(request.name))
        self._sync_reconfigure()
        return ConnectCameraResponse(**result)

    def disconnect_camera(self, _request):
        self._call(self.device.disconnect)
        return StdEmptyResponse()

    def _acquisition(self, action):
        result = self._call(action)
        self._sync_reconfigure()
        return result

    def start_acquisition(self, _request):
        result = self._acquisition(self.device.start_acquisition)
        if not result["success"]:
            rospy.logerr("phoxi_camera: %s", result["message"])
        return StdEmptyResponse()

    def stop_acquisition(self, _request):
        result = self._acquisition(self.device.stop_acquisition)
        if not result["success"]:
            rospy.logerr("phoxi_camera: %s", result["message"])
        return StdEmptyResponse()

    def start_acquisition_v2(self, _request):
        return EmptyResponse(**self._acquisition(self.device.start_acquisition))

    def stop_acquisition_v2(self, _request):
        return EmptyResponse(**self._acquisition(self.device.stop_acquisition))

    def trigger_image(self, _request):
        """Trigger a frame and answer its id; nothing is published (``get_frame(id)`` does that), as the driver."""
        try:
            frame = self.capture(-1)
        except REQUEST_ERRORS as exc:
            return TriggerImageResponse(id=-1, message=str(exc), success=False)
        finally:
            self._sync_reconfigure()
        return TriggerImageResponse(id=frame.index, message=OK, success=True)

    def get_frame(self, request):
        """Publish frame ``in_`` (a new one for < 0) on every enabled topic."""
        try:
            self.publish_frame(self.capture(int(request.in_)))
        except REQUEST_ERRORS as exc:
            return GetFrameResponse(message=str(exc), success=False)
        finally:
            self._sync_reconfigure()
        return GetFrameResponse(message=OK, success=True)

    def save_frame(self, request):
        try:
            with self.lock:
                frame, write = self.device.capture_for_saving(
                    int(request.in_), request.path, self, self.config["organized_cloud"]
                )
            path = write()  # outside the lock: other frame calls go on while the file is written
        except REQUEST_ERRORS as exc:
            return SaveFrameResponse(message=str(exc), success=False)
        finally:
            self._sync_reconfigure()
        rospy.loginfo("phoxi_camera: frame %d written to %s", frame.index, path)
        return SaveFrameResponse(message=OK, success=True)

    def save_last_frame(self, request):
        try:
            with self.lock:
                write = self.device.last_frame_writer(request.file_path, self.config["organized_cloud"])
            path = write()  # outside the lock: a PTX export must not hold up get_frame and the others
        except REQUEST_ERRORS as exc:
            return SaveLastFrameResponse(message=str(exc), success=False)
        rospy.loginfo("phoxi_camera: last frame written to %s", path)
        return SaveLastFrameResponse(message=OK, success=True)

    def get_hardware_identification(self, _request):
        try:
            self.device.require_connected()
        except PhoxiError as exc:
            return GetHardwareIdentificationResponse(message=str(exc), success=False)
        return GetHardwareIdentificationResponse(
            hardware_identification=self.device.hardware_identification, message=OK, success=True
        )

    def get_supported_capturing_modes(self, _request):
        try:
            sizes = self.device.supported_capturing_modes()
        except PhoxiError as exc:
            return GetSupportedCapturingModesResponse(message=str(exc), success=False)
        modes = [PhoXiSize(Width=w, Height=h) for w, h in sizes]
        return GetSupportedCapturingModesResponse(supported_capturing_modes=modes, message=OK, success=True)

    def set_coordinate_space(self, request):
        result = self._call(lambda: self.device.set_coordinate_space(int(request.coordinates_space)))
        if int(request.coordinates_space) != NO_VALUE_SPACE:
            self._sync_reconfigure()
        return SetCoordinatesSpaceResponse(**result)

    def set_transformation(self, request):
        def apply():
            matrix = _matrix_from_tf(request.transform)
            self.device.set_transformation(matrix, request.coordinates_space, request.set_space, request.save_settings)

        result = self._call(apply)
        # the space switched whatever set_space said (as the driver's scanner); the reconfigure value shows it
        self._sync_reconfigure()
        return SetTransformationMatrixResponse(**result)

    # ------------------------------------------------------------------------------ reconfigure, status
    def _reconfigure(self, config, level):
        with self.lock:
            refusal = self.device.reconfigure(config, level, previous=self.config)
            if refusal:
                rospy.logwarn("phoxi_camera: %s", refusal)
            self.config = {name: config[name] for name in phoxi_config.defaults}
        return config

    def publish_diagnostics(self):
        level, message = self.device.status()
        status = DiagnosticStatus(
            level=DIAGNOSTIC_LEVELS[level],
            name="phoxi_camera: PhoXi3Dscanner",
            message=message,
            hardware_id="none",  # as the driver's diagnostic updater
            values=[KeyValue(key, value) for key, value in self.device.diagnostic_values()],
        )
        self.diagnostics.publish(DiagnosticArray(header=Header(stamp=rospy.Time.now()), status=[status]))


def main():
    run_node("phoxi_camera", PhoxiCameraNode)
