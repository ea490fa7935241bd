// MRTK 2: CoreServices.InputSystem.EyeGazeProvider (eye tracking enabled in the MRTK input
// profile's pointer settings). Its gaze is already in Unity world.
#if FG_MRTK2
using Microsoft.MixedReality.Toolkit;
using UnityEngine;

namespace FabricGuidance.Headset.Unity
{
    public sealed class Mrtk2EyeGazeSource : MonoBehaviour, IGazeSource
    {
        public bool TryGetGaze(out Vector3 origin, out Vector3 direction, out bool eyeTrackingValid)
        {
            var eye = CoreServices.InputSystem?.EyeGazeProvider;
            if (eye == null)
            {
                origin = direction = Vector3.zero;
                eyeTrackingValid = false;
                return false;
            }
            origin = eye.GazeOrigin;
            direction = eye.GazeDirection;
            eyeTrackingValid = eye.IsEyeTrackingEnabledAndValid && eye.IsEyeCalibrationValid == true;
            return true;
        }
    }
}
#endif
