// MRTK 3 / OpenXR: the eye gaze pose of the OpenXR Eye Gaze Interaction Profile (enable it in
// Project Settings > XR Plug-in Management > OpenXR > Interaction Profiles). Bind the actions
// to <EyeGaze>/pose/position, <EyeGaze>/pose/rotation, <EyeGaze>/pose/isTracked and
// <EyeGaze>/pose/trackingState. The pose counts only while isTracked is set and trackingState
// has both position and rotation: before consent, without an eye tracker or when tracking is
// lost the actions keep their defaults ((0,0,0), (0,0,0,0)) or the last pose, and the core
// then sends the head gaze marked not valid. The pose is in the XR rig's tracking space:
// trackingSpace (the rig's Camera Offset) takes it to Unity world, where the head pose
// (Camera.main) and the targets are.
#if FG_INPUT_SYSTEM
using UnityEngine;
using UnityEngine.InputSystem;

namespace FabricGuidance.Headset.Unity
{
    public sealed class OpenXrEyeGazeSource : MonoBehaviour, IEyeGazeSource
    {
        /// <summary>UnityEngine.XR.InputTrackingState.Position | Rotation.</summary>
        const int PositionAndRotation = 1 | 2;

        public InputActionProperty position;
        public InputActionProperty rotation;
        public InputActionProperty isTracked;
        public InputActionProperty trackingState;
        [Tooltip("The XR rig's Camera Offset transform")]
        public Transform trackingSpace;

        void OnEnable()
        {
            position.action?.Enable();
            rotation.action?.Enable();
            isTracked.action?.Enable();
            trackingState.action?.Enable();
        }

        public bool TryGetEyeGaze(out Vec3 origin, out Vec3 direction)
        {
            origin = direction = default(Vec3);
            if (position.action == null || rotation.action == null || isTracked.action == null) return false;
            if (isTracked.action.ReadValue<float>() < 0.5f) return false;
            if (trackingState.action != null && (trackingState.action.ReadValue<int>() & PositionAndRotation) != PositionAndRotation)
                return false;
            Vector3 p = position.action.ReadValue<Vector3>();
            Quaternion r = rotation.action.ReadValue<Quaternion>();
            Vector3 forward = r * Vector3.forward;   // (0,0,0) for the default rotation: the core refuses it
            if (trackingSpace != null)
            {
                p = trackingSpace.TransformPoint(p);
                forward = trackingSpace.TransformDirection(forward);
            }
            origin = new Vec3(p.x, p.y, p.z);
            direction = new Vec3(forward.x, forward.y, forward.z);
            return true;
        }
    }
}
#endif
