import sys, math, zlib, struct, collections, statistics as st
seq, out = sys.argv[1], sys.argv[2]
FX,FY,CX,CY=None,None,None,None
for l in open(f'{seq}/camera.yaml'):
    if l.startswith('Camera.fx'): FX=float(l.split(':')[1])
    if l.startswith('Camera.fy'): FY=float(l.split(':')[1])
    if l.startswith('Camera.cx'): CX=float(l.split(':')[1])
    if l.startswith('Camera.cy'): CY=float(l.split(':')[1])
def qrot(qx,qy,qz,qw):
    return [[1-2*(qy*qy+qz*qz),2*(qx*qy-qz*qw),2*(qx*qz+qy*qw)],
            [2*(qx*qy+qz*qw),1-2*(qx*qx+qz*qz),2*(qy*qz-qx*qw)],
            [2*(qx*qz-qy*qw),2*(qy*qz+qx*qw),1-2*(qx*qx+qy*qy)]]
def load_traj(p):
    d={}
    for l in open(p):
        if l.startswith('#') or not l.strip(): continue
        f=l.split(); t='%.6f'%float(f[0]); v=list(map(float,f[1:]))
        d[t]=(qrot(*v[3:7]),v[0:3])   # R_wc, C
    return d
def mv(R,x): return [sum(R[i][j]*x[j] for j in range(3)) for i in range(3)]
def mtv(R,x): return [sum(R[j][i]*x[j] for j in range(3)) for i in range(3)]
def w2c(P,X):
    R,C=P; return mtv(R,[X[i]-C[i] for i in range(3)])
def c2w(P,x):
    R,C=P; y=mv(R,x); return [y[i]+C[i] for i in range(3)]
gt=load_traj(f'{seq}/groundtruth.txt'); est=load_traj(f'{out}/keyframes.txt')
pts=[]
for l in open(f'{out}/mapdump.txt'):
    f=l.split()
    if f[0]=='P': pts.append(([float(x) for x in f[1:4]],[]))
    else: pts[-1][1].append(('%.6f'%float(f[1]),float(f[2]),float(f[3]),int(f[4]),float(f[5])))
# A: map depth in est KF vs depth sample
ratio=collections.defaultdict(list)
for X,obs in pts:
    for t,u,v,o,d in obs:
        if d<=0 or t not in est: continue
        z=w2c(est[t],X)[2]
        ratio[o].append(z/d)
allr=[r for o in ratio for r in ratio[o]]
print('A map z (est pose) / depth sample: median %.5f mean %.5f n=%d'%(st.median(allr),st.mean(allr),len(allr)))
for o in sorted(ratio): print('   oct %d median %.5f n=%d'%(o,st.median(ratio[o]),len(ratio[o])))
# C: two-view depth factor with GT poses
def proj(x): return (FX*x[0]/x[2]+CX, FY*x[1]/x[2]+CY)
num=collections.defaultdict(float); den=collections.defaultdict(float); lam=collections.defaultdict(list)
res=collections.defaultdict(lambda:[0.0,0.0,0])
for X,obs in pts:
    obs=[o for o in obs if o[4]>0 and o[0] in gt]
    for a in obs:
        for b in obs:
            if a is b: continue
            ta,ua,va,oa,da=a; tb,ub,vb,ob,db=b
            ray=[(ua-CX)/FX,(va-CY)/FY,1.0]
            def pb(l):
                Xw=c2w(gt[ta],[r*da*l for r in ray]); xc=w2c(gt[tb],Xw)
                return proj(xc)
            p1=pb(1.0); p2=pb(1.001)
            J=[(p2[0]-p1[0])/0.001,(p2[1]-p1[1])/0.001]
            r=[ub-p1[0],vb-p1[1]]
            jj=J[0]**2+J[1]**2
            if jj<25: continue  # <0.5 px per 10 %
            if r[0]**2+r[1]**2>16: continue
            key=(oa,ob)
            num[oa]+= J[0]*r[0]+J[1]*r[1]; den[oa]+=jj
            lam[oa].append(1+(J[0]*r[0]+J[1]*r[1])/jj)
            rr=res[ob]; rr[0]+=r[0]; rr[1]+=r[1]; rr[2]+=1
tn=sum(num.values()); td=sum(den.values())
alll=[x for o in lam for x in lam[o]]
print('C GT-pose two-view depth factor lambda (true depth = lambda*sample; by octave of the depth-giving obs): LS %.5f median %.5f n=%d'%(1+tn/td, st.median(alll), len(alll)))
for o in sorted(lam): print('   oct %d LS %.5f median %.5f n=%d'%(o,1+num[o]/den[o],st.median(lam[o]),len(lam[o])))
print('   mean residual (observed - predicted) in view b by octave of b:')
for o in sorted(res): r=res[o]; print('   oct %d du %.3f dv %.3f n=%d'%(o,r[0]/r[2],r[1]/r[2],r[2]))
# D: KF-to-KF translation scale
ks=sorted(est); sn=0; sd=0
for i in range(1,len(ks)):
    a,b=ks[i-1],ks[i]
    if a not in gt or b not in gt: continue
    te=[est[b][1][j]-est[a][1][j] for j in range(3)]; tg=[gt[b][1][j]-gt[a][1][j] for j in range(3)]
    sn+=math.sqrt(sum(x*x for x in te)); sd+=math.sqrt(sum(x*x for x in tg))
print('D sum |dt_est| / sum |dt_gt| over consecutive KFs: %.5f (%d KFs)'%(sn/sd,len(ks)))
