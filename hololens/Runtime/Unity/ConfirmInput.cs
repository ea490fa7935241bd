// The wearer's confirm press ("I am there"): the HoloLens clicker or an air tap. Each press
// calls HeadsetLinkBehaviour.Confirm on the main thread, which stamps it with the headset clock
// and sends it to gaze_bridge (kind "confirm", docs/headset_wire_format.md).
// - Input System / OpenXR (MRTK 3): bind `select` to the hands' select, e.g.
//   <HoloLensHand>{LeftHand}/select and <HoloLensHand>{RightHand}/select (Microsoft Hand
//   Interaction Profile), or to MRTK 3's select actions.
// - MRTK 2: a global handler of MRTK's "Select" input action (air tap, clicker, "select" spoken).
using UnityEngine;
#if FG_INPUT_SYSTEM
using UnityEngine.InputSystem;
#endif
#if FG_MRTK2
using Microsoft.MixedReality.Toolkit;
using Microsoft.MixedReality.Toolkit.Input;
#endif

namespace FabricGuidance.Headset.Unity
{
    [RequireComponent(typeof(HeadsetLinkBehaviour))]
    public sealed class ConfirmInput : MonoBehaviour
#if FG_MRTK2
        , IMixedRealityInputHandler
#endif
    {
#if FG_INPUT_SYSTEM
        [Tooltip("Performed once per press: the hands' select (air tap) or the clicker")]
        public InputActionProperty select;
#endif
#if FG_MRTK2
        [Tooltip("MRTK 2's input action for a press (the default profile's \"Select\")")]
        public MixedRealityInputAction selectAction;
#endif
        HeadsetLinkBehaviour link;

        void Awake() { link = GetComponent<HeadsetLinkBehaviour>(); }

        void OnEnable()
        {
#if FG_INPUT_SYSTEM
            if (select.action != null)
            {
                select.action.performed += OnSelect;
                select.action.Enable();
            }
#endif
#if FG_MRTK2
            CoreServices.InputSystem?.RegisterHandler<IMixedRealityInputHandler>(this);
#endif
        }

        void OnDisable()
        {
#if FG_INPUT_SYSTEM
            if (select.action != null) select.action.performed -= OnSelect;
#endif
#if FG_MRTK2
            CoreServices.InputSystem?.UnregisterHandler<IMixedRealityInputHandler>(this);
#endif
        }

#if FG_INPUT_SYSTEM
        void OnSelect(InputAction.CallbackContext context) { link.Confirm(); }
#endif
#if FG_MRTK2
        public void OnInputDown(InputEventData eventData)
        {
            if (eventData.MixedRealityInputAction == selectAction) link.Confirm();
        }

        public void OnInputUp(InputEventData eventData) { }
#endif
    }
}
