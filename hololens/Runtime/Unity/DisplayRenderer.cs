// Draws the display state with primitives: targets as 0.1 m spheres (the active one red, the
// others magenta, live objects cyan), the speed task's dummies as grey spheres, a caption for
// Algorithm 1's prompts and condition 4's phrase, and a short green flash on "found".
using System.Collections.Generic;
using UnityEngine;

namespace FabricGuidance.Headset.Unity
{
    [RequireComponent(typeof(HeadsetLinkBehaviour))]
    public sealed class DisplayRenderer : MonoBehaviour
    {
        public float targetDiameterM = 0.1f;
        public float flashS = 0.5f;
        [Tooltip("A TextMesh about 1.5 m ahead of the camera for prompts and phrases")]
        public TextMesh caption;

        readonly List<GameObject> targets = new List<GameObject>();
        readonly List<GameObject> dummies = new List<GameObject>();
        uint shownSet;
        float flashUntil;
        string flashed = "";
        DisplayState state;

        void Start()
        {
            // The session (and its display state) exists before HeadsetLinkBehaviour.Start runs.
            state = GetComponent<HeadsetLinkBehaviour>().Session.Display;
            state.EventShown += m => { if (m.Event == "found") { flashed = m.Target; flashUntil = Time.time + flashS; } };
        }

        void LateUpdate()   // after HeadsetLinkBehaviour.Update has pumped the messages
        {
            if (state == null) return;
            Resize(targets, state.Targets.Count, targetDiameterM);
            for (int i = 0; i < state.Targets.Count; i++)
            {
                var t = state.Targets[i];
                targets[i].transform.position = new Vector3((float)t.Position.X, (float)t.Position.Y, (float)t.Position.Z);
                Color c = t.Id == state.Active ? Color.red : (t.Role == "live" ? Color.cyan : Color.magenta);
                if (t.Id == flashed && Time.time < flashUntil) c = Color.green;
                targets[i].GetComponent<Renderer>().material.color = c;
            }
            if (state.DummySet != shownSet)
            {
                shownSet = state.DummySet;
                Resize(dummies, state.Dummies.Count, 2f * (float)state.DummyRadiusM);
                for (int i = 0; i < state.Dummies.Count; i++)
                {
                    var p = state.Dummies[i];
                    dummies[i].transform.position = new Vector3((float)p.X, (float)p.Y, (float)p.Z);
                    dummies[i].GetComponent<Renderer>().material.color = Color.grey;
                }
            }
            if (caption != null)
                caption.text = state.Prompt != "" ? state.Prompt : state.Phrase;
        }

        static void Resize(List<GameObject> pool, int n, float diameter)
        {
            while (pool.Count < n)
            {
                var s = GameObject.CreatePrimitive(PrimitiveType.Sphere);
                Destroy(s.GetComponent<Collider>());   // nothing to hit: the gaze must pass through
                pool.Add(s);
            }
            for (int i = 0; i < pool.Count; i++)
            {
                pool[i].SetActive(i < n);
                pool[i].transform.localScale = Vector3.one * diameter;
            }
        }
    }
}
