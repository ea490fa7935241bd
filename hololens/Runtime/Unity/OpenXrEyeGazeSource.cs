// MRTK 3 / OpenXR: the eye gaze pose of the OpenXR Eye Gaze Interaction Profile (enable it in
// Project Settings > XR Plug-in Management > OpenXR > Interaction Profiles). Bind the three
// actions to <EyeGaze>/pose/position, <EyeGaze>/pose/rotation and <EyeGaze>/pose/isTracked.
// The pose is in the XR rig's tracking space: trackingSpace (the rig's Camera Offset) takes it
// to Unity world, where the head pose (Camera.main) and the targets are.
#if FG_INPUT_SYSTEM
using UnityEngine;
using UnityEngine.InputSystem;

namespace FabricGuidance.Headset.Unity
{
    public sealed class OpenXrEyeGazeSource : MonoBehaviour, IGazeSource
    {
        public InputActionProperty position;
        public InputActionProperty rotation;
        public InputActionProperty isTracked;
        [Tooltip("The XR rig's Camera Offset transform")]
        public Transform trackingSpace;

        void OnEnable()
        {
            position.action?.Enable();
            rotation.action?.Enable();
            isTracked.action?.Enable();
        }

        public bool TryGetGaze(out Vector3 origin, out Vector3 direction, out bool eyeTrackingValid)
        {
            Vector3 p = position.action.ReadValue<Vector3>();
            Quaternion r = rotation.action.ReadValue<Quaternion>();
            eyeTrackingValid = isTracked.action.ReadValue<float>() > 0.5f;
            origin = trackingSpace != null ? trackingSpace.TransformPoint(p) : p;
            Vector3 forward = r * Vector3.forward;
            direction = trackingSpace != null ? trackingSpace.TransformDirection(forward) : forward;
            return true;   // invalid samples are still sent, marked so: gaze_bridge decides
        }
    }
}
#endif
